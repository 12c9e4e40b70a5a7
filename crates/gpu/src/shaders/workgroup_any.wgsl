// Appended by the host to the kernels that skip work no thread of a workgroup has (chunked.wgsl,
// weight_grad.wgsl): WGSL has no includes.

var<workgroup> hits: atomic<u32>;
var<workgroup> live: u32;

// Whether `found` holds for any thread of the workgroup; the answer is the same for all of
// them (uniform), so a caller can skip work that holds barriers. Every thread must call it.
fn workgroup_any(found: bool, lid: u32) -> bool {
    if (found) {
        atomicOr(&hits, 1u);
    }
    workgroupBarrier();
    if (lid == 0u) {
        live = atomicLoad(&hits);
        atomicStore(&hits, 0u);
    }
    return workgroupUniformLoad(&live) != 0u;
}
