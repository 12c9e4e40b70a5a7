// The rulebook baseline (the paper's Algorithm 1) on the device, one offset at a time: gather
// the offset's source rows into a dense buffer, multiply by the offset's weights (a tiled GEMM
// with both tiles in workgroup memory), scatter-add the products into the destination rows.
// Within one offset no destination repeats, so the scatter needs no atomics, and offsets run
// in index order, so every output is summed in the same order on every run.
// Also here: the separate batch-norm + ReLU pass of the standard algorithm, and the weight
// gradient (one thread per weight, pairs in list order: deterministic).
//
// Pairs buffer: [in rows (n_pairs) | out rows (n_pairs) | offset starts (kv + 1)].

struct Params {
    rows: u32,      // pairs of this offset (gather, gemm, scatter); elements (bn_relu)
    c_src: u32,
    c_dst: u32,
    pair_base: u32, // first pair of this offset
    n_pairs: u32,
    swap: u32,      // 1: read from out rows, write to in rows (input gradient)
    w_base: u32,    // first weight of this offset
    kv: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read> pairs: array<u32>;
@group(0) @binding(3) var<storage, read> weights: array<f32>;
@group(0) @binding(4) var<storage, read_write> dst: array<f32>;
@group(0) @binding(5) var<storage, read> second: array<f32>;

var<workgroup> ta: array<f32, 256>;
var<workgroup> tb: array<f32, 256>;

fn flat_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * 64u;
}

fn source_row(j: u32) -> u32 {
    return pairs[p.pair_base + j + p.swap * p.n_pairs];
}

fn dest_row(j: u32) -> u32 {
    return pairs[p.pair_base + j + (1u - p.swap) * p.n_pairs];
}

// dst[j, c] = src[source_row(j), c]
@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.rows * p.c_src) {
        return;
    }
    let j = e / p.c_src;
    let c = e % p.c_src;
    dst[e] = src[source_row(j) * p.c_src + c];
}

// dst[j, o] = sum_c src[j, c] weights[w_base + c c_dst + o], 16 x 16 tiles.
@compute @workgroup_size(16, 16)
fn gemm(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let j = (wid.x + wid.y * nwg.x) * 16u + lid.y;
    let o = wid.z * 16u + lid.x;
    var acc = 0.0;
    for (var c0 = 0u; c0 < p.c_src; c0 += 16u) {
        let ca = c0 + lid.x;
        var a = 0.0;
        if (j < p.rows && ca < p.c_src) {
            a = src[j * p.c_src + ca];
        }
        ta[lid.y * 16u + lid.x] = a;
        let cb = c0 + lid.y;
        var b = 0.0;
        if (cb < p.c_src && o < p.c_dst) {
            b = weights[p.w_base + cb * p.c_dst + o];
        }
        tb[lid.y * 16u + lid.x] = b;
        workgroupBarrier();
        for (var q = 0u; q < 16u; q++) {
            acc += ta[lid.y * 16u + q] * tb[q * 16u + lid.x];
        }
        workgroupBarrier();
    }
    if (j < p.rows && o < p.c_dst) {
        dst[j * p.c_dst + o] = acc;
    }
}

// dst[dest_row(j), o] += src[j, o]
@compute @workgroup_size(64)
fn scatter(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.rows * p.c_dst) {
        return;
    }
    let j = e / p.c_dst;
    let o = e % p.c_dst;
    let at = dest_row(j) * p.c_dst + o;
    dst[at] = dst[at] + src[e];
}

// dst[e] = max(0, src[e] weights[c] + weights[c_src + c]) with c = e mod c_src.
@compute @workgroup_size(64)
fn bn_relu(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.rows) {
        return;
    }
    let c = e % p.c_src;
    dst[e] = max(0.0, src[e] * weights[c] + weights[p.c_src + c]);
}

// dst[k, c, o] = sum over the pairs of offset k of src[in, c] second[out, o]
// (src = x [n_in, c_src], second = dy [n_out, c_dst]).
@compute @workgroup_size(64)
fn weight_grad(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = flat_index(gid, nwg);
    if (e >= p.kv * p.c_src * p.c_dst) {
        return;
    }
    let k = e / (p.c_src * p.c_dst);
    let c = (e / p.c_dst) % p.c_src;
    let o = e % p.c_dst;
    let starts = 2u * p.n_pairs;
    var acc = 0.0;
    for (var q = pairs[starts + k]; q < pairs[starts + k + 1u]; q++) {
        acc += src[pairs[q] * p.c_src + c] * second[pairs[p.n_pairs + q] * p.c_dst + o];
    }
    dst[e] = acc;
}
