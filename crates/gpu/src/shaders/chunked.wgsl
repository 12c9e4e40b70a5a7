// The chunk-based convolution on the device, shaped for a GPU: the host's chunk plan fixes the
// order of the destinations (chunks of nearby voxels, Z-order within a chunk, chunk after
// chunk), and one workgroup computes a tile of 64 consecutive destinations of that order by 64
// output channels. Per kernel offset, the tile's 64 source rows (a global neighbour table in
// plan order) are gathered 16 channels at a time into workgroup memory with the folded batch
// norm + ReLU applied on the way in, next to a 16 x 64 weight tile; each of the 256 threads
// then accumulates a 4 x 4 block (4 destinations x 4 channels) in registers: 16 multiply-adds
// per two vec4 reads of workgroup memory. An offset that no destination of the tile has is
// skipped as a whole; plan order keeps neighbours together, so flat surfaces skip about a third
// of the offsets and the gathered rows are mostly in the L2 cache.
//
// The first version of this kernel staged each chunk's input region in workgroup memory and
// gave every thread one output channel of 8 rows (two workgroup reads per multiply-add, 64
// threads): on an H100 it ran at 0.5 TFLOP/s, a third of the rulebook kernel's speed
// (docs/gpu.md, "H100").
//
// Every destination belongs to one tile and is written once, by one thread: no atomics, a fixed
// summation order (offsets, then channel tiles, then channels), the same bits on every run.
//
// Plan buffer (u32): dst_rows [n_dst] | table [n_dst, kv] (the source row of every
// destination at every offset, or EMPTY), destinations in plan order.

struct Params {
    c_in: u32,
    c_out: u32,
    kv: u32,
    n_dst: u32,
    flags: u32,        // bit 0: batch norm + ReLU on the input; bit 1: add to y
    o_dst_rows: u32,
    o_table: u32,
    _pad: u32,
}

const EMPTY: u32 = 0xffffffffu;
const TR: u32 = 64u; // destinations per tile
const TO: u32 = 64u; // output channels per tile
const CT: u32 = 16u; // input channels per step

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> w: array<f32>;
@group(0) @binding(3) var<storage, read> bn: array<f32>;
@group(0) @binding(4) var<storage, read> plan: array<u32>;
@group(0) @binding(5) var<storage, read_write> y: array<f32>;

var<workgroup> a_tile: array<vec4<f32>, 256>; // [CT][TR / 4]: channel c, destinations 4q..4q+3
var<workgroup> w_tile: array<vec4<f32>, 256>; // [CT][TO / 4]: channel c, outputs 4q..4q+3
var<workgroup> src: array<u32, 64>;           // the tile's source rows at the current offset
var<workgroup> hits: atomic<u32>;
var<workgroup> live: u32;

fn load_x(row: u32, c: u32) -> f32 {
    let v = x[row * p.c_in + c];
    if ((p.flags & 1u) != 0u) {
        return max(0.0, v * bn[c] + bn[p.c_in + c]);
    }
    return v;
}

@compute @workgroup_size(256)
fn forward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let t0 = (wid.x + wid.y * nwg.x) * TR;
    if (t0 >= p.n_dst) {
        return;
    }
    let o0 = wid.z * TO;
    // Compute roles: destinations 4 tr .. 4 tr + 3, channels o0 + 4 tc .. + 3.
    let tr = lid / 16u;
    let tc = lid % 16u;
    // Load roles: destination lr, channels lc .. lc + 3 of the step; weight row wc, outputs
    // wo .. wo + 3.
    let lr = lid / 4u;
    let lc = (lid % 4u) * 4u;
    let wc = lid / 16u;
    let wo = o0 + (lid % 16u) * 4u;
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    for (var k = 0u; k < p.kv; k++) {
        if (lid < TR) {
            var s = EMPTY;
            if (t0 + lid < p.n_dst) {
                s = plan[p.o_table + (t0 + lid) * p.kv + k];
            }
            src[lid] = s;
            if (s != EMPTY) {
                atomicOr(&hits, 1u);
            }
        }
        workgroupBarrier();
        if (lid == 0u) {
            live = atomicLoad(&hits);
            atomicStore(&hits, 0u);
        }
        // Offsets no destination of the tile has are skipped by the whole workgroup.
        if (workgroupUniformLoad(&live) == 0u) {
            continue;
        }
        let s = src[lr];
        for (var c0 = 0u; c0 < p.c_in; c0 += CT) {
            for (var j = 0u; j < 4u; j++) {
                let c = c0 + lc + j;
                var v = 0.0;
                if (s != EMPTY && c < p.c_in) {
                    v = load_x(s, c);
                }
                a_tile[(lc + j) * 16u + lr / 4u][lr % 4u] = v;
            }
            let c = c0 + wc;
            var wv = vec4<f32>(0.0);
            if (c < p.c_in) {
                let base = (k * p.c_in + c) * p.c_out;
                if (wo < p.c_out) {
                    wv.x = w[base + wo];
                }
                if (wo + 1u < p.c_out) {
                    wv.y = w[base + wo + 1u];
                }
                if (wo + 2u < p.c_out) {
                    wv.z = w[base + wo + 2u];
                }
                if (wo + 3u < p.c_out) {
                    wv.w = w[base + wo + 3u];
                }
            }
            w_tile[wc * 16u + (lid % 16u)] = wv;
            workgroupBarrier();
            for (var cc = 0u; cc < CT; cc++) {
                let a = a_tile[cc * 16u + tr];
                let b = w_tile[cc * 16u + tc];
                acc0 += a.x * b;
                acc1 += a.y * b;
                acc2 += a.z * b;
                acc3 += a.w * b;
            }
            workgroupBarrier();
        }
    }
    let o = o0 + 4u * tc;
    store(t0 + 4u * tr, o, acc0);
    store(t0 + 4u * tr + 1u, o, acc1);
    store(t0 + 4u * tr + 2u, o, acc2);
    store(t0 + 4u * tr + 3u, o, acc3);
}

// Writes (or, with the accumulate flag, adds) channels o .. o + 3 of destination t (plan
// order).
fn store(t: u32, o: u32, v: vec4<f32>) {
    if (t >= p.n_dst) {
        return;
    }
    let base = plan[p.o_dst_rows + t] * p.c_out;
    for (var j = 0u; j < 4u; j++) {
        if (o + j < p.c_out) {
            if ((p.flags & 2u) != 0u) {
                y[base + o + j] = y[base + o + j] + v[j];
            } else {
                y[base + o + j] = v[j];
            }
        }
    }
}
