//! `--device cpu|gpu|auto`: where the network's convolutions (and `bench conv`'s kernels)
//! run. `gpu` needs a build with the cargo feature `gpu` and a Vulkan adapter, and fails with
//! the reason otherwise; `auto` takes the GPU when both are there and the CPU, with a note on
//! stderr saying why, when not. The default is the CPU.

use std::sync::Arc;

use semrecon_gpu::{GpuContext, GpuEngine};
use semrecon_net::Device;
use semrecon_sparse::ConvAlgorithm;

/// `--device`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceChoice {
    /// The CPU engine.
    #[default]
    Cpu,
    /// The GPU engine (wgpu on Vulkan); an error when there is none.
    Gpu,
    /// The GPU engine when available, else the CPU with a note.
    Auto,
}

/// The `--device` option, flattened into the commands that run the network.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct DeviceArgs {
    /// Where the convolutions run: cpu, gpu (a build with `--features gpu` and a Vulkan
    /// adapter) or auto (the GPU when there is one, else the CPU with a note).
    #[arg(long, value_enum, default_value_t = DeviceChoice::Cpu)]
    pub device: DeviceChoice,
}

impl DeviceArgs {
    /// The opened GPU for `gpu` and `auto` when there is one; `None` for the CPU.
    ///
    /// # Errors
    /// With `gpu`, the reason there is no usable GPU.
    pub fn gpu_context(&self) -> anyhow::Result<Option<Arc<GpuContext>>> {
        match self.device {
            DeviceChoice::Cpu => Ok(None),
            DeviceChoice::Gpu => {
                let ctx = GpuContext::new().map_err(|e| anyhow::anyhow!("--device gpu: {e}"))?;
                note_software(&ctx);
                Ok(Some(Arc::new(ctx)))
            }
            DeviceChoice::Auto => match GpuContext::new() {
                Ok(ctx) => {
                    note_software(&ctx);
                    Ok(Some(Arc::new(ctx)))
                }
                Err(e) => {
                    eprintln!("note: --device auto runs on the CPU: {e}");
                    Ok(None)
                }
            },
        }
    }

    /// The network's device.
    ///
    /// # Errors
    /// As [`Self::gpu_context`].
    pub fn network_device(&self) -> anyhow::Result<Device> {
        Ok(match self.gpu_context()? {
            Some(ctx) => Device::Gpu(GpuEngine::with_context(ctx, ConvAlgorithm::Chunked)),
            None => Device::Cpu,
        })
    }
}

/// Says when the adapter is a CPU software rasteriser: right results, timings of no GPU.
fn note_software(ctx: &GpuContext) {
    if ctx.is_software() {
        eprintln!(
            "note: the GPU adapter {} is a software rasteriser on the CPU (lavapipe): results are right, \
             timings say nothing about a GPU",
            ctx.adapter_name()
        );
    }
}
