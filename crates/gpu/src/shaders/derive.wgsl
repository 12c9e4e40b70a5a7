// Kernel parameters computed on the device from voxel counts the host does not know yet (the
// coarser levels of a hierarchy, crates/gpu/src/hierarchy.rs): word j of the output is
// counts[sel[j]] * mul[j] + add[j] (just add[j] where sel[j] is NONE). The output buffer is
// then bound as the next kernels' uniform parameters, so that a whole hierarchy is recorded
// without waiting for its counts.

struct Spec {
    // sel[8] | mul[8] | add[8], four words per vector.
    words: array<vec4<u32>, 6>,
}

const NONE: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> spec: Spec;
@group(0) @binding(1) var<storage, read> counts: array<u32>;
@group(0) @binding(2) var<storage, read_write> out: array<u32>;

fn word(i: u32) -> u32 {
    return spec.words[i / 4u][i % 4u];
}

@compute @workgroup_size(8)
fn derive(@builtin(local_invocation_index) j: u32) {
    var v = word(16u + j);
    let sel = word(j);
    if (sel != NONE) {
        v += counts[sel] * word(8u + j);
    }
    out[j] = v;
}
