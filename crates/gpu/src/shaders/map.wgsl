// Submanifold kernel maps on the device: a hash table of voxel coordinates (open addressing,
// linear probing, slots claimed with a compare-exchange), then one look-up per (voxel, offset)
// writing the [n, K^3] neighbour table. Slots hold row indices, not keys: a probe compares the
// coordinates of the row it finds, so no 64-bit keys are needed (WGSL has no 64-bit atomics).
// Offset numbering as in crates/sparse kernel_map.rs: k = ((dz + r) K + dy + r) K + dx + r.

struct Params {
    n: u32,
    mask: u32,
    ks: u32,
    kv: u32,
}

const EMPTY: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> coords: array<vec4<i32>>;
@group(0) @binding(2) var<storage, read_write> slots: array<atomic<u32>>;
// [0]: 1 + the highest row found to repeat an earlier coordinate; [1]: 1 when the table filled.
@group(0) @binding(3) var<storage, read_write> status: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> table: array<u32>;

fn hash(c: vec4<i32>) -> u32 {
    var h = bitcast<u32>(c.x) * 0x8da6b343u;
    h ^= bitcast<u32>(c.y) * 0xd8163841u;
    h ^= bitcast<u32>(c.z) * 0xcb1ab31fu;
    h ^= bitcast<u32>(c.w) * 0x165667b1u;
    h ^= h >> 16u;
    h *= 0x7feb352du;
    h ^= h >> 15u;
    h *= 0x846ca68bu;
    h ^= h >> 16u;
    return h;
}

@compute @workgroup_size(64)
fn insert(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 64u;
    if (i >= p.n) {
        return;
    }
    let c = coords[i];
    var s = hash(c) & p.mask;
    var probes = 0u;
    loop {
        if (probes > p.mask) {
            atomicMax(&status[1], 1u);
            return;
        }
        let r = atomicCompareExchangeWeak(&slots[s], EMPTY, i);
        if (r.exchanged) {
            return;
        }
        // A weak exchange may fail spuriously on an empty slot: try the same slot again.
        if (r.old_value != EMPTY) {
            if (all(coords[r.old_value] == c)) {
                atomicMax(&status[0], max(i, r.old_value) + 1u);
                return;
            }
            s = (s + 1u) & p.mask;
            probes += 1u;
        }
    }
}

@compute @workgroup_size(64)
fn lookup(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = gid.x + gid.y * nwg.x * 64u;
    if (t >= p.n * p.kv) {
        return;
    }
    let u = t / p.kv;
    let k = t % p.kv;
    let r = i32(p.ks / 2u);
    let d = vec4<i32>(i32(k % p.ks) - r, i32((k / p.ks) % p.ks) - r, i32(k / (p.ks * p.ks)) - r, 0);
    let q = coords[u] + d;
    var s = hash(q) & p.mask;
    var probes = 0u;
    loop {
        let e = atomicLoad(&slots[s]);
        if (e == EMPTY || probes > p.mask) {
            table[t] = EMPTY;
            return;
        }
        if (all(coords[e] == q)) {
            table[t] = e;
            return;
        }
        s = (s + 1u) & p.mask;
        probes += 1u;
    }
}
