//! Without any Vulkan driver the engine reports a clear error (its own process: the driver
//! search path is set before anything opens Vulkan).

use semrecon_gpu::{GpuEngine, GpuError};
use semrecon_sparse::ConvAlgorithm;

#[test]
fn no_adapter_is_an_error_not_a_panic() {
    // The Vulkan loader reads these before enumerating drivers; nothing else in this test
    // binary runs concurrently.
    std::env::set_var("VK_ICD_FILENAMES", "/nonexistent/semrecon-no-driver.json");
    std::env::set_var("VK_DRIVER_FILES", "/nonexistent/semrecon-no-driver.json");
    match GpuEngine::new(ConvAlgorithm::Chunked) {
        Err(GpuError::NoAdapter(m)) => eprintln!("as expected: {m}"),
        Err(GpuError::NotBuilt) => eprintln!("built without the gpu feature"),
        Err(e) => panic!("expected NoAdapter, got {e}"),
        Ok(_) => panic!("an adapter was found with no driver installed"),
    }
}
