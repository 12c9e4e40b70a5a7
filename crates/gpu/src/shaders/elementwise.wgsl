// The element-wise steps of the network between its convolutions, on resident tensors: the
// attention gate, the weighted row gather (trilinear interpolation across levels), the head's
// bias and the per-row argmax. One thread per output value (per row for the argmax), each
// summing in the CPU engine's order (crates/sparse/src/elementwise.rs), so results match it to
// rounding (exp, and any fused multiply-add the compiler forms).
//
// Gather table buffer (u32): rows [n, per_row] | weights [n, per_row] as f32 bits.

struct Params {
    n: u32,       // rows
    c: u32,       // channels per row (gate: gated channels; argmax: scores)
    stride: u32,  // values per source row (gather)
    per_row: u32, // table entries per row (gather)
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read> table: array<u32>;
@group(0) @binding(3) var<storage, read_write> dst: array<f32>;
@group(0) @binding(4) var<storage, read_write> labels: array<u32>;

fn flat_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * 64u;
}

// dst[r, i] *= sigmoid(dst[r, c]) for i < c, rows of c + 1 values. The gate column itself is
// only read, so the threads of a row never race.
@compute @workgroup_size(64)
fn gate(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.n * p.c) {
        return;
    }
    let row = (e / p.c) * (p.c + 1u);
    let at = row + e % p.c;
    let s = 1.0 / (1.0 + exp(-dst[row + p.c]));
    dst[at] = dst[at] * s;
}

// dst[u, i] += sum_q w[u, q] src[rows[u, q] * stride + i], entries of weight zero skipped.
@compute @workgroup_size(64)
fn gather_add(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.n * p.c) {
        return;
    }
    let u = e / p.c;
    let i = e % p.c;
    let base = u * p.per_row;
    let weights = p.n * p.per_row;
    var acc = dst[e];
    for (var q = 0u; q < p.per_row; q++) {
        let w = bitcast<f32>(table[weights + base + q]);
        if (w != 0.0) {
            acc += w * src[table[base + q] * p.stride + i];
        }
    }
    dst[e] = acc;
}

// dst[r, i] += src[i] (the bias), rows of c values.
@compute @workgroup_size(64)
fn add_bias(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.n * p.c) {
        return;
    }
    dst[e] = dst[e] + src[e % p.c];
}

// labels[r] = the first index of the largest of src[r, ..c].
@compute @workgroup_size(64)
fn argmax(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = flat_index(gid, nwg);
    if (r >= p.n) {
        return;
    }
    let base = r * p.c;
    var best = 0u;
    for (var k = 1u; k < p.c; k++) {
        if (src[base + k] > src[base + best]) {
            best = k;
        }
    }
    labels[r] = best;
}

// dst[i] = (stride != 0 ? dst[i] : 0) + sum over the splits s in order of src[s n + i]: the
// chunked kernel's partial sums over ranges of kernel offsets (c: splits; stride: 1 to add to
// the output's contents).
@compute @workgroup_size(64)
fn split_sum(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.n) {
        return;
    }
    var acc = 0.0;
    if (p.stride != 0u) {
        acc = dst[e];
    }
    for (var s = 0u; s < p.c; s++) {
        acc += src[s * p.n + e];
    }
    dst[e] = acc;
}
