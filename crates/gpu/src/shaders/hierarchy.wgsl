// The coarser levels of a voxel hierarchy on the device (crates/gpu/src/hierarchy.rs): the
// parents floor(u / 2) of a level's voxels, deduplicated in a hash table whose slots keep the
// lowest fine row of each parent (so the coarse voxels come out in order of first appearance,
// the CPU's order: a prefix sum over "is the first child" flags numbers them); the strided
// layer's two neighbour tables; and the cross-scale trilinear interpolation tables.
// The hash function (hash.wgsl) is appended by the host.

struct Params {
    // Rows of the level the kernel walks.
    n: u32,
    // Hash mask (insert), or the coarse level's rows (emit: where its tables start), or the
    // interpolation's levels apart (interp).
    a: u32,
    // Blocks of the prefix sum, or the coarse level's rows (interp).
    b: u32,
    // A value to fill with (fill) or the modulus of the row numbers (rows).
    c: u32,
}

const EMPTY: u32 = 0xffffffffu;
const SCAN: u32 = 256u;

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> coords: array<vec4<i32>>;
@group(0) @binding(2) var<storage, read_write> slots: array<atomic<u32>>;
// The hash slot of every fine row.
@group(0) @binding(3) var<storage, read_write> slot_of: array<u32>;
// Per fine row: 1 for the first child of its parent (flag), then its exclusive prefix sum.
@group(0) @binding(4) var<storage, read_write> rank: array<u32>;
// Per block of the prefix sum: its total, then its exclusive prefix.
@group(0) @binding(5) var<storage, read_write> block_sums: array<u32>;
// [0]: coarse voxels; [1]: 1 when the table filled.
@group(0) @binding(6) var<storage, read_write> status: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read_write> parent: array<u32>;
@group(0) @binding(8) var<storage, read_write> coarse: array<vec4<i32>>;
// The strided layer's plans: [coarse rows | coarse x 8 fine rows] and
// [fine rows | fine x 8 coarse rows] (EMPTY where absent).
@group(0) @binding(9) var<storage, read_write> down: array<u32>;
@group(0) @binding(10) var<storage, read_write> up: array<u32>;
// A plan of the coarse level: [rows | rows x 27 neighbours] (interp reads the table).
@group(0) @binding(11) var<storage, read> coarse_plan: array<u32>;
// Interpolation: [n x 8 rows | n x 8 weight bits].
@group(0) @binding(12) var<storage, read_write> gather: array<u32>;

var<workgroup> partial: array<u32, SCAN>;

fn parent_of(c: vec4<i32>) -> vec4<i32> {
    // Arithmetic shifts: floor(u / 2) for negative coordinates too.
    return vec4<i32>(c.x >> 1u, c.y >> 1u, c.z >> 1u, c.w);
}

fn flat(gid: vec3<u32>, nwg: vec3<u32>, size: u32) -> u32 {
    return gid.x + gid.y * nwg.x * size;
}

// Every parent into the table; a slot keeps the lowest fine row of its parent.
@compute @workgroup_size(64)
fn insert(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg, 64u);
    if (i >= p.n) {
        return;
    }
    let key = parent_of(coords[i]);
    var s = hash(key) & p.a;
    var probes = 0u;
    loop {
        if (probes > p.a) {
            atomicMax(&status[1], 1u);
            return;
        }
        let r = atomicCompareExchangeWeak(&slots[s], EMPTY, i);
        if (r.exchanged) {
            slot_of[i] = s;
            return;
        }
        // A weak exchange may fail spuriously on an empty slot: try the same slot again.
        if (r.old_value != EMPTY) {
            if (all(parent_of(coords[r.old_value]) == key)) {
                // Slots only ever go down from a claimed row to a lower one of the same parent.
                atomicMin(&slots[s], i);
                slot_of[i] = s;
                return;
            }
            s = (s + 1u) & p.a;
            probes += 1u;
        }
    }
}

// 1 for the first child (the lowest row) of every parent.
@compute @workgroup_size(64)
fn first_child(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg, 64u);
    if (i >= p.n) {
        return;
    }
    rank[i] = select(0u, 1u, atomicLoad(&slots[slot_of[i]]) == i);
}

// `partial` (filled by every thread, then a barrier) to its inclusive prefix sum, Hillis-Steele:
// after the step of `d`, entry j holds the sum of the 2d entries up to j. Every thread of the
// workgroup calls it (it holds barriers).
fn scan_partial(lid: u32) {
    for (var d = 1u; d < SCAN; d *= 2u) {
        var add = 0u;
        if (lid >= d) {
            add = partial[lid - d];
        }
        workgroupBarrier();
        partial[lid] += add;
        workgroupBarrier();
    }
}

// Prefix sum, step 1: each block of SCAN flags scanned in workgroup memory (exclusive), its
// total kept.
@compute @workgroup_size(256)
fn scan_blocks(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * SCAN + lid;
    var v = 0u;
    if (i < p.n) {
        v = rank[i];
    }
    partial[lid] = v;
    workgroupBarrier();
    scan_partial(lid);
    if (i < p.n) {
        rank[i] = partial[lid] - v;
    }
    if (lid == SCAN - 1u && block < p.b) {
        block_sums[block] = partial[lid];
    }
}

// Step 2, one workgroup: the block totals to their exclusive prefix; the grand total is the
// number of coarse voxels.
@compute @workgroup_size(256)
fn scan_totals(@builtin(local_invocation_index) lid: u32) {
    let per = (p.b + SCAN - 1u) / SCAN;
    let first = min(lid * per, p.b);
    let last = min(first + per, p.b);
    var own = 0u;
    for (var j = first; j < last; j += 1u) {
        own += block_sums[j];
    }
    partial[lid] = own;
    workgroupBarrier();
    scan_partial(lid);
    var running = partial[lid] - own;
    for (var j = first; j < last; j += 1u) {
        let v = block_sums[j];
        block_sums[j] = running;
        running += v;
    }
    if (lid == SCAN - 1u) {
        atomicStore(&status[0], partial[lid]);
    }
}

// Step 3: the block prefixes added.
@compute @workgroup_size(256)
fn scan_add(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * SCAN + lid;
    if (i < p.n) {
        rank[i] += block_sums[block];
    }
}

// Every fine row finds its parent's number (the rank of its first child), the first children
// write the coarse voxels, and both strided tables get their entry at the child's offset
// k = (x & 1) + 2 (y & 1) + 4 (z & 1). `a`: coarse rows.
@compute @workgroup_size(64)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg, 64u);
    if (i >= p.n) {
        return;
    }
    let c = coords[i];
    let first = atomicLoad(&slots[slot_of[i]]);
    let row = rank[first];
    parent[i] = row;
    if (first == i) {
        coarse[row] = parent_of(c);
    }
    let k = u32(c.x & 1) + 2u * u32(c.y & 1) + 4u * u32(c.z & 1);
    down[p.a + row * 8u + k] = i;
    up[p.n + i * 8u + k] = row;
}

// `buffer[i] = c` for i < n (EMPTY tables before the strided layers' scattered writes).
@compute @workgroup_size(64)
fn fill(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg, 64u);
    if (i < p.n) {
        down[i] = p.c;
    }
}

// `buffer[i] = i % c` for i < n: a plan's destination rows, and the pointwise layer's
// [rows | rows] plan.
@compute @workgroup_size(64)
fn rows(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg, 64u);
    if (i < p.n) {
        down[i] = i % p.c;
    }
}

// One step up the hierarchy: ancestor rows replaced by their parents' rows.
@compute @workgroup_size(64)
fn ancestor(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg, 64u);
    if (i < p.n) {
        up[i] = parent[up[i]];
    }
}

// The two coarse voxels bracketing a fine voxel along one axis (offset from the ancestor,
// weight), from the fine coordinate's remainder below the ancestor's size 2^shift: as
// crates/net geometry.rs interp_table, in f32 (the weights are dyadic: exact).
struct Bracket {
    d0: i32,
    w0: f32,
    d1: i32,
    w1: f32,
}

fn bracket(x: i32, shift: u32) -> Bracket {
    let rem = x & ((1 << shift) - 1);
    let pos = (f32(rem) + 0.5) / f32(1u << shift) - 0.5;
    if (pos < 0.0) {
        return Bracket(-1, -pos, 0, 1.0 + pos);
    }
    return Bracket(0, 1.0 - pos, 1, pos);
}

// Trilinear interpolation from the level `a` levels up (its rows `b`; ancestors in `up`) to
// every fine voxel: 8 (row, weight) per fine row, absent corners weight 0 (row: the ancestor),
// the rest renormalised. The corners lie in the ancestor's 3x3x3 neighbourhood, read from the
// coarse level's submanifold plan.
@compute @workgroup_size(64)
fn interp(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let u = flat(gid, nwg, 64u);
    if (u >= p.n) {
        return;
    }
    let c = coords[u];
    let a = up[u];
    let bx = bracket(c.x, p.a);
    let by = bracket(c.y, p.a);
    let bz = bracket(c.z, p.a);
    let dx = array<i32, 2>(bx.d0, bx.d1);
    let wx = array<f32, 2>(bx.w0, bx.w1);
    let dy = array<i32, 2>(by.d0, by.d1);
    let wy = array<f32, 2>(by.w0, by.w1);
    let dz = array<i32, 2>(bz.d0, bz.d1);
    let wz = array<f32, 2>(bz.w0, bz.w1);
    var w: array<f32, 8>;
    var total = 0.0;
    var q = 0u;
    for (var iz = 0u; iz < 2u; iz += 1u) {
        for (var iy = 0u; iy < 2u; iy += 1u) {
            for (var ix = 0u; ix < 2u; ix += 1u) {
                let k = u32((dz[iz] + 1) * 9 + (dy[iy] + 1) * 3 + dx[ix] + 1);
                var row = a;
                if (k != 13u) {
                    row = coarse_plan[p.b + a * 27u + k];
                }
                if (row != EMPTY) {
                    w[q] = wx[ix] * wy[iy] * wz[iz];
                    gather[u * 8u + q] = row;
                    total += w[q];
                } else {
                    w[q] = 0.0;
                    gather[u * 8u + q] = a;
                }
                q += 1u;
            }
        }
    }
    for (var j = 0u; j < 8u; j += 1u) {
        gather[(p.n + u) * 8u + j] = bitcast<u32>(w[j] / total);
    }
}
