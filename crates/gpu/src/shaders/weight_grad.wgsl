// The weight gradient of the chunked algorithm: dw[k, c, o] = sum over the destinations u that
// have a neighbour at offset k of x[table[u, k], c] * dy[u, o], on the forward plan's
// neighbour table (destinations in plan order). One workgroup of 256 threads owns a 16 x 64
// block of dw[k] (input channels c0.., output channels o0..) over one segment of the
// destinations, walked in blocks of 32: the block's gathered input rows (transposed) and
// output-gradient rows go to workgroup memory, and each thread accumulates 4 output channels
// of one input channel over the 32 rows. Blocks with no neighbour at offset k are skipped.
// With several segments (so that a GPU has enough workgroups) each writes its partial sums to
// its own slice and `reduce_segments` adds the slices in segment order. Every weight is summed
// in destination order, then segment order: no atomics, the same bits on every run.
//
// The rulebook's weight gradient (rulebook.wgsl) gives every weight its own thread looping over
// the offset's pairs; that stays the baseline.

struct Params {
    c_in: u32,
    c_out: u32,
    kv: u32,
    n_dst: u32,
    o_dst_rows: u32,
    o_table: u32,
    c_blocks: u32,    // ceil(c_in / 16)
    segments: u32,    // workgroup x = (segment * kv + k) * c_blocks + input-channel block
    segment_rows: u32, // destinations per segment (a multiple of RB)
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const EMPTY: u32 = 0xffffffffu;
const RB: u32 = 32u; // destinations per block

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> dy: array<f32>;
@group(0) @binding(3) var<storage, read> plan: array<u32>;
@group(0) @binding(4) var<storage, read_write> dw: array<f32>;

var<workgroup> xt: array<f32, 512>;        // [16 channels][RB rows]
var<workgroup> dyt: array<vec4<f32>, 512>; // [RB rows][16 quads of output channels]
var<workgroup> src: array<u32, 32>;
var<workgroup> dst: array<u32, 32>;

@compute @workgroup_size(256)
fn weight_grad(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let g = wid.x + wid.y * nwg.x;
    if (g >= p.segments * p.kv * p.c_blocks) {
        return;
    }
    let seg = g / (p.kv * p.c_blocks);
    let k = (g / p.c_blocks) % p.kv;
    let c0 = (g % p.c_blocks) * 16u;
    let first = seg * p.segment_rows;
    let end = min(p.n_dst, first + p.segment_rows);
    let o0 = wid.z * 64u;
    // Compute role: input channel ci, output channels o0 + 4 cq .. + 3.
    let ci = lid / 16u;
    let cq = lid % 16u;
    // Load roles: row lr; input channels 2 lx, 2 lx + 1; output channels 8 lx .. 8 lx + 7.
    let lr = lid / 8u;
    let lx = lid % 8u;
    var acc = vec4<f32>(0.0);
    for (var t0 = first; t0 < end; t0 += RB) {
        var found = EMPTY;
        if (lid < RB) {
            var d = 0u;
            if (t0 + lid < end) {
                found = plan[p.o_table + (t0 + lid) * p.kv + k];
                d = plan[p.o_dst_rows + t0 + lid];
            }
            src[lid] = found;
            dst[lid] = d;
        }
        if (!workgroup_any(found != EMPTY, lid)) {
            continue;
        }
        let s = src[lr];
        let d = dst[lr];
        for (var j = 0u; j < 2u; j++) {
            let c = c0 + 2u * lx + j;
            var v = 0.0;
            if (s != EMPTY && c < p.c_in) {
                v = x[s * p.c_in + c];
            }
            xt[(2u * lx + j) * RB + lr] = v;
        }
        for (var q = 0u; q < 2u; q++) {
            var v = vec4<f32>(0.0);
            if (s != EMPTY) {
                for (var j = 0u; j < 4u; j++) {
                    let o = o0 + 8u * lx + 4u * q + j;
                    if (o < p.c_out) {
                        v[j] = dy[d * p.c_out + o];
                    }
                }
            }
            dyt[lr * 16u + 2u * lx + q] = v;
        }
        workgroupBarrier();
        for (var r = 0u; r < RB; r++) {
            acc += xt[ci * RB + r] * dyt[r * 16u + cq];
        }
        workgroupBarrier();
    }
    let c = c0 + ci;
    if (c < p.c_in) {
        let base = ((seg * p.kv + k) * p.c_in + c) * p.c_out;
        for (var j = 0u; j < 4u; j++) {
            let o = o0 + 4u * cq + j;
            if (o < p.c_out) {
                dw[base + o] = acc[j];
            }
        }
    }
}

// dw[e] = sum over the segments s (in order) of partial[s, e], one thread per weight.
@group(0) @binding(5) var<storage, read> partial: array<f32>;
@group(0) @binding(6) var<storage, read_write> total: array<f32>;

@compute @workgroup_size(64)
fn reduce_segments(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = gid.x + gid.y * nwg.x * 64u;
    let n = p.kv * p.c_in * p.c_out;
    if (e >= n) {
        return;
    }
    var acc = 0.0;
    for (var s = 0u; s < p.segments; s++) {
        acc += partial[s * n + e];
    }
    total[e] = acc;
}
