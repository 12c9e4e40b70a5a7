// The chunk-based convolution on the device, shaped for a GPU: the host's chunk plan fixes the
// order of the destinations (chunks of nearby voxels, Z-order within a chunk, chunk after
// chunk), and one workgroup of 256 threads computes a tile of TR consecutive destinations of
// that order by TO output channels (64 x 64, or 128 x 32 for narrow layers). Per kernel offset,
// the tile's source rows (a global neighbour table in plan order) are gathered 16 channels at a
// time into workgroup memory with the folded batch norm + ReLU applied on the way in, next to a
// 16 x TO weight tile; each thread then accumulates a 4 x 4 block (4 destinations x 4 channels)
// in registers: 16 multiply-adds per two vec4 reads of workgroup memory. An offset that no
// destination of the tile has is skipped as a whole; plan order keeps neighbours together, so
// flat surfaces skip about a third of the offsets and the gathered rows are mostly in the L2
// cache.
//
// The first version of this kernel staged each chunk's input region in workgroup memory and
// gave every thread one output channel of 8 rows (two workgroup reads per multiply-add, 64
// threads): on an H100 it ran at 0.5 TFLOP/s, a third of the rulebook kernel's speed
// (docs/gpu.md, "H100").
//
// Every destination belongs to one tile and is written once, by one thread: no atomics, a fixed
// summation order (offsets, then channel tiles, then channels), the same bits on every run.
// Layers too small to fill the GPU split their (offset, channel step) sequence into ranges
// (one range per group of workgroups along z, into its own slice of partial sums), and
// elementwise.wgsl's split_sum adds the slices in order: more workgroups, each with a shorter
// serial loop, still one dispatch.
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
    // Ranges of the (kernel offset, input-channel step) sequence (1: all of it; else the
    // workgroup's range, from its z index, writes its own slice of partial sums, `slice`
    // values apart), and output-channel tiles.
    splits: u32,
    channel_tiles: u32,
    slice: u32,
    _pad0: u32,
    _pad1: u32,
}

const EMPTY: u32 = 0xffffffffu;
// Tile shape: TR destinations x TO output channels over 256 threads, each a block of 4 RQ
// destinations x 4 CQ channels. The host compiles this source once per shape of
// `CHUNKED_TILES` (replacing the four lines below) and picks by the layer's output channels,
// so that narrow layers do not idle half a tile and wide ones reuse each value read from
// workgroup memory for more multiply-adds.
const TR: u32 = 64u;
const TO: u32 = 64u;
const RQ: u32 = 1u;
const CQ: u32 = 1u;
const CT: u32 = 16u;               // input channels per step
const TCOLS: u32 = TO / (4u * CQ); // thread columns of the compute layout
const A_LANES: u32 = 256u / TR;    // threads loading one destination's CT channels
const A_VALS: u32 = CT / A_LANES;  // values each of them loads
const W_VALS: u32 = TO / 16u;      // weights each thread loads per step

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> w: array<f32>;
@group(0) @binding(3) var<storage, read> bn: array<f32>;
@group(0) @binding(4) var<storage, read> plan: array<u32>;
@group(0) @binding(5) var<storage, read_write> y: array<f32>;

var<workgroup> a_tile: array<vec4<f32>, 4u * TR>; // [CT][TR / 4]: channel c, destinations 4q..4q+3
var<workgroup> w_tile: array<vec4<f32>, 4u * TO>; // [CT][TO / 4]: channel c, outputs 4q..4q+3
var<workgroup> src: array<u32, TR>;               // the tile's source rows at the current offset

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
    let split = wid.z / p.channel_tiles;
    let o0 = (wid.z % p.channel_tiles) * TO;
    // A split owns a range of the (offset, input-channel step) sequence.
    let csteps = (p.c_in + CT - 1u) / CT;
    let s_begin = split * p.kv * csteps / p.splits;
    let s_end = (split + 1u) * p.kv * csteps / p.splits;
    let k_begin = s_begin / csteps;
    let k_end = (s_end + csteps - 1u) / csteps;
    let y_offset = split * p.slice;
    // Compute roles: destinations 4 RQ tr .. + 4 RQ - 1, channels o0 + 4 CQ tc .. + 4 CQ - 1.
    let tr = lid / TCOLS;
    let tc = lid % TCOLS;
    // Load roles: destination lr, channels lc .. lc + A_VALS - 1 of the step; weight row wc,
    // tile outputs wq .. wq + W_VALS - 1.
    let lr = lid / A_LANES;
    let lc = (lid % A_LANES) * A_VALS;
    let wc = lid / 16u;
    let wq = (lid % 16u) * W_VALS;
    // acc<row><channel quad>: separate variables, not an array (an indexed array may live in
    // slow per-thread memory); the unused ones of smaller shapes fold away.
    var acc00 = vec4<f32>(0.0);
    var acc10 = vec4<f32>(0.0);
    var acc20 = vec4<f32>(0.0);
    var acc30 = vec4<f32>(0.0);
    var acc40 = vec4<f32>(0.0);
    var acc50 = vec4<f32>(0.0);
    var acc60 = vec4<f32>(0.0);
    var acc70 = vec4<f32>(0.0);
    var acc01 = vec4<f32>(0.0);
    var acc11 = vec4<f32>(0.0);
    var acc21 = vec4<f32>(0.0);
    var acc31 = vec4<f32>(0.0);
    var acc41 = vec4<f32>(0.0);
    var acc51 = vec4<f32>(0.0);
    var acc61 = vec4<f32>(0.0);
    var acc71 = vec4<f32>(0.0);
    for (var k = k_begin; k < k_end; k++) {
        var found = EMPTY;
        if (lid < TR) {
            if (t0 + lid < p.n_dst) {
                found = plan[p.o_table + (t0 + lid) * p.kv + k];
            }
            src[lid] = found;
        }
        // Offsets no destination of the tile has are skipped by the whole workgroup.
        if (!workgroup_any(found != EMPTY, lid)) {
            continue;
        }
        let s = src[lr];
        let c_first = (max(s_begin, k * csteps) - k * csteps) * CT;
        let c_last = (min(s_end, (k + 1u) * csteps) - k * csteps) * CT;
        for (var c0 = c_first; c0 < c_last; c0 += CT) {
            for (var j = 0u; j < A_VALS; j++) {
                let c = c0 + lc + j;
                var v = 0.0;
                if (s != EMPTY && c < p.c_in) {
                    v = load_x(s, c);
                }
                a_tile[(lc + j) * (TR / 4u) + lr / 4u][lr % 4u] = v;
            }
            let c = c0 + wc;
            for (var j = 0u; j < W_VALS; j++) {
                let q = wq + j;
                var v = 0.0;
                if (c < p.c_in && o0 + q < p.c_out) {
                    v = w[(k * p.c_in + c) * p.c_out + o0 + q];
                }
                w_tile[wc * (TO / 4u) + q / 4u][q % 4u] = v;
            }
            workgroupBarrier();
            for (var cc = 0u; cc < CT; cc++) {
                let a0 = a_tile[cc * (TR / 4u) + tr * RQ];
                let b0 = w_tile[cc * (TO / 4u) + tc * CQ];
                acc00 += a0.x * b0;
                acc10 += a0.y * b0;
                acc20 += a0.z * b0;
                acc30 += a0.w * b0;
                var b1 = vec4<f32>(0.0);
                if (CQ > 1u) {
                    b1 = w_tile[cc * (TO / 4u) + tc * CQ + 1u];
                    acc01 += a0.x * b1;
                    acc11 += a0.y * b1;
                    acc21 += a0.z * b1;
                    acc31 += a0.w * b1;
                }
                if (RQ > 1u) {
                    let a1 = a_tile[cc * (TR / 4u) + tr * RQ + 1u];
                    acc40 += a1.x * b0;
                    acc50 += a1.y * b0;
                    acc60 += a1.z * b0;
                    acc70 += a1.w * b0;
                    if (CQ > 1u) {
                        acc41 += a1.x * b1;
                        acc51 += a1.y * b1;
                        acc61 += a1.z * b1;
                        acc71 += a1.w * b1;
                    }
                }
            }
            workgroupBarrier();
        }
    }
    let r = t0 + 4u * RQ * tr;
    let o = o0 + 4u * CQ * tc;
    store(r, o, acc00, y_offset);
    store(r + 1u, o, acc10, y_offset);
    store(r + 2u, o, acc20, y_offset);
    store(r + 3u, o, acc30, y_offset);
    if (CQ > 1u) {
        store(r, o + 4u, acc01, y_offset);
        store(r + 1u, o + 4u, acc11, y_offset);
        store(r + 2u, o + 4u, acc21, y_offset);
        store(r + 3u, o + 4u, acc31, y_offset);
    }
    if (RQ > 1u) {
        store(r + 4u, o, acc40, y_offset);
        store(r + 5u, o, acc50, y_offset);
        store(r + 6u, o, acc60, y_offset);
        store(r + 7u, o, acc70, y_offset);
        if (CQ > 1u) {
            store(r + 4u, o + 4u, acc41, y_offset);
            store(r + 5u, o + 4u, acc51, y_offset);
            store(r + 6u, o + 4u, acc61, y_offset);
            store(r + 7u, o + 4u, acc71, y_offset);
        }
    }
}

// Writes (or, with the accumulate flag, adds) channels o .. o + 3 of destination t (plan
// order), `y_offset` values into y.
fn store(t: u32, o: u32, v: vec4<f32>, y_offset: u32) {
    if (t >= p.n_dst) {
        return;
    }
    let base = y_offset + plan[p.o_dst_rows + t] * p.c_out;
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
