// Submanifold kernel maps on the device: a hash table of voxel coordinates (open addressing,
// linear probing, slots claimed with a compare-exchange), then one look-up per (voxel, offset)
// writing the [n, K^3] neighbour table. Slots hold row indices, not keys: a probe compares the
// coordinates of the row it finds, so no 64-bit keys are needed (WGSL has no 64-bit atomics).
// Offset numbering as in crates/sparse kernel_map.rs: k = ((dz + r) K + dy + r) K + dx + r.
// The look-up can write the table after `n` destination rows 0..n (the chunked kernel's plan
// layout, with `rows` set) and counts the neighbour pairs it finds (status[2]).

struct Params {
    n: u32,
    mask: u32,
    ks: u32,
    kv: u32,
    // 1: write the destination rows 0..n first and the table after them.
    rows: u32,
}

const EMPTY: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> coords: array<vec4<i32>>;
@group(0) @binding(2) var<storage, read_write> slots: array<atomic<u32>>;
// [0]: 1 + the highest row found to repeat an earlier coordinate; [1]: 1 when the table filled;
// [2]: neighbour pairs found by the look-up.
@group(0) @binding(3) var<storage, read_write> status: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> table: array<u32>;

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

var<workgroup> found: atomic<u32>;

@compute @workgroup_size(64)
fn lookup(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    if (lid == 0u) {
        atomicStore(&found, 0u);
    }
    workgroupBarrier();
    let t = gid.x + gid.y * nwg.x * 64u;
    let base = p.rows * p.n;
    if (t < p.n * p.kv) {
        let u = t / p.kv;
        let k = t % p.kv;
        if (p.rows != 0u && k == 0u) {
            table[u] = u;
        }
        let r = i32(p.ks / 2u);
        let d = vec4<i32>(i32(k % p.ks) - r, i32((k / p.ks) % p.ks) - r, i32(k / (p.ks * p.ks)) - r, 0);
        let q = coords[u] + d;
        var s = hash(q) & p.mask;
        var probes = 0u;
        var row = EMPTY;
        loop {
            let e = atomicLoad(&slots[s]);
            if (e == EMPTY || probes > p.mask) {
                break;
            }
            if (all(coords[e] == q)) {
                row = e;
                break;
            }
            s = (s + 1u) & p.mask;
            probes += 1u;
        }
        table[base + t] = row;
        if (row != EMPTY) {
            atomicAdd(&found, 1u);
        }
    }
    // Integer counts: the same total in any order.
    workgroupBarrier();
    if (lid == 0u) {
        atomicAdd(&status[2], atomicLoad(&found));
    }
}
