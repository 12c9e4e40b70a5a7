// The chunk-based convolution (the paper's Algorithm 2) on the device: one workgroup per chunk
// and block of 16 output channels. The chunk's input region (the distinct input rows its
// outputs read, planned on the host by crates/sparse ChunkPlan) is copied into workgroup
// memory 16 channels at a time, with the folded batch norm and ReLU applied on the way in;
// then, per group of 4 kernel offsets, their 16 x 16 weight tiles join it in workgroup memory
// (one pair of barriers per group: barriers are what small chunks pay most for) and every thread
// accumulates 8 output rows of one channel from the region (32 rows a pass, each pass
// reloading the region and weight tiles). The 8 accumulators are separate variables: a
// dynamically indexed array would live in slow per-thread memory on GPUs (and on lavapipe). Each output row belongs to one
// chunk, so it is written once, by one thread: no atomics, and a fixed summation order
// (channel tiles, then offsets, then channels), the same bits on every run.
//
// Regions larger than the tile (176 rows; the planner keeps them near its 256-row budget)
// read their remaining rows straight from global memory: slower, never wrong.
//
// Plan buffer (u32): dst_start [chunks + 1] | dst_rows | src_start [chunks + 1] | src_rows |
// local table [n_dst, kv] (chunk-local region index of every destination's input at every
// offset, or EMPTY), destinations in plan order.

struct Params {
    c_in: u32,
    c_out: u32,
    kv: u32,
    n_chunks: u32,
    flags: u32,        // bit 0: batch norm + ReLU on the input; bit 1: add to y
    o_dst_start: u32,
    o_dst_rows: u32,
    o_src_start: u32,
    o_src_rows: u32,
    o_table: u32,
    _pad0: u32,
    _pad1: u32,
}

const EMPTY: u32 = 0xffffffffu;
const CT: u32 = 16u;   // channels per region tile
const OT: u32 = 16u;   // output channels per workgroup
const CAP: u32 = 176u; // region rows in workgroup memory
const KG: u32 = 4u;    // offsets whose weight tiles share one pair of barriers
const ROWS: u32 = 32u; // output rows per pass: 4 row lanes x 8 accumulators

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> w: array<f32>;
@group(0) @binding(3) var<storage, read> bn: array<f32>;
@group(0) @binding(4) var<storage, read> plan: array<u32>;
@group(0) @binding(5) var<storage, read_write> y: array<f32>;

var<workgroup> region: array<f32, 2816>; // CAP x CT
var<workgroup> wt: array<f32, 1024>;     // KG x CT x OT
var<workgroup> chunk_meta: vec4<u32>;    // d0, m, s0, n_region

fn load_x(row: u32, c: u32) -> f32 {
    let v = x[row * p.c_in + c];
    if ((p.flags & 1u) != 0u) {
        return max(0.0, v * bn[c] + bn[p.c_in + c]);
    }
    return v;
}

@compute @workgroup_size(64)
fn forward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let chunk = wid.x + wid.y * nwg.x;
    if (chunk >= p.n_chunks) {
        return;
    }
    if (lid == 0u) {
        let d0 = plan[p.o_dst_start + chunk];
        let s0 = plan[p.o_src_start + chunk];
        chunk_meta = vec4<u32>(d0, plan[p.o_dst_start + chunk + 1u] - d0, s0, plan[p.o_src_start + chunk + 1u] - s0);
    }
    // Chunk sizes come from memory: make them provably uniform for the barriers below.
    let cm = workgroupUniformLoad(&chunk_meta);
    let d0 = cm.x;
    let m = cm.y;
    let s0 = cm.z;
    let n_region = cm.w;
    let in_tile = min(n_region, CAP);
    let oc = lid % OT;
    let lane = lid / OT; // 0..4: rows lane, lane + 4, ..., lane + 28 of a pass
    let o = wid.z * OT + oc;

    for (var rp = 0u; rp < m; rp += ROWS) {
        var a0 = 0.0;
        var a1 = 0.0;
        var a2 = 0.0;
        var a3 = 0.0;
        var a4 = 0.0;
        var a5 = 0.0;
        var a6 = 0.0;
        var a7 = 0.0;
        let j0 = rp + lane;
        for (var c0 = 0u; c0 < p.c_in; c0 += CT) {
            workgroupBarrier();
            for (var e = lid; e < in_tile * CT; e += 64u) {
                let c = c0 + e % CT;
                var v = 0.0;
                if (c < p.c_in) {
                    v = load_x(plan[p.o_src_rows + s0 + e / CT], c);
                }
                region[e] = v;
            }
            for (var kb = 0u; kb < p.kv; kb += KG) {
                workgroupBarrier();
                for (var e = lid; e < KG * CT * OT; e += 64u) {
                    let k = kb + e / (CT * OT);
                    let c = c0 + (e / OT) % CT;
                    let oo = wid.z * OT + e % OT;
                    var v = 0.0;
                    if (k < p.kv && c < p.c_in && oo < p.c_out) {
                        v = w[(k * p.c_in + c) * p.c_out + oo];
                    }
                    wt[e] = v;
                }
                workgroupBarrier();
                for (var g = 0u; g < min(KG, p.kv - kb); g++) {
                    a0 += row_sum(j0, m, d0, s0, c0, kb, g, oc);
                    a1 += row_sum(j0 + 4u, m, d0, s0, c0, kb, g, oc);
                    a2 += row_sum(j0 + 8u, m, d0, s0, c0, kb, g, oc);
                    a3 += row_sum(j0 + 12u, m, d0, s0, c0, kb, g, oc);
                    a4 += row_sum(j0 + 16u, m, d0, s0, c0, kb, g, oc);
                    a5 += row_sum(j0 + 20u, m, d0, s0, c0, kb, g, oc);
                    a6 += row_sum(j0 + 24u, m, d0, s0, c0, kb, g, oc);
                    a7 += row_sum(j0 + 28u, m, d0, s0, c0, kb, g, oc);
                }
            }
        }
        if (o < p.c_out) {
            store(j0, m, d0, o, a0);
            store(j0 + 4u, m, d0, o, a1);
            store(j0 + 8u, m, d0, o, a2);
            store(j0 + 12u, m, d0, o, a3);
            store(j0 + 16u, m, d0, o, a4);
            store(j0 + 20u, m, d0, o, a5);
            store(j0 + 24u, m, d0, o, a6);
            store(j0 + 28u, m, d0, o, a7);
        }
    }
}

// The contribution of the current channel tile and offset kb + g (weight tile g) to chunk row
// j, channel oc.
fn row_sum(j: u32, m: u32, d0: u32, s0: u32, c0: u32, kb: u32, g: u32, oc: u32) -> f32 {
    if (j >= m) {
        return 0.0;
    }
    let s = plan[p.o_table + (d0 + j) * p.kv + kb + g];
    if (s == EMPTY) {
        return 0.0;
    }
    var acc = 0.0;
    if (s < CAP) {
        for (var c = 0u; c < CT; c++) {
            acc += region[s * CT + c] * wt[(g * CT + c) * OT + oc];
        }
    } else {
        let row = plan[p.o_src_rows + s0 + s];
        for (var c = 0u; c < CT; c++) {
            if (c0 + c < p.c_in) {
                acc += load_x(row, c0 + c) * wt[(g * CT + c) * OT + oc];
            }
        }
    }
    return acc;
}

// Writes (or, with the accumulate flag, adds) one output value of chunk row j.
fn store(j: u32, m: u32, d0: u32, o: u32, v: f32) {
    if (j >= m) {
        return;
    }
    let at = plan[p.o_dst_rows + d0 + j] * p.c_out + o;
    if ((p.flags & 2u) != 0u) {
        y[at] = y[at] + v;
    } else {
        y[at] = v;
    }
}
