//! `app` layer: the commands' use cases, each scheduling the pipeline and the renderers below it —
//! [`offline`] (`render` on a chosen backend, orbit cameras), [`window`] (the `view` loop), [`xr_session`]
//! (`xr`), [`live`] (capture -> pipeline worker, frame dropping, video folders) and [`neural`] (the neural
//! renderer of the interactive paths).

pub mod live;
pub mod neural;
pub mod offline;
pub mod window;
pub mod xr_session;

/// Which engine computes the person.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU reference pipeline (the window still presents through Vulkan).
    Cpu,
    /// The Vulkan per-view passes.
    #[default]
    Vulkan,
    /// The Vulkan passes on a GPU; the CPU reference when the only Vulkan device is a software rasteriser
    /// (lavapipe), where the Vulkan passes share the CPU's cores and run several times slower than the reference.
    Auto,
}

impl Backend {
    /// The backend to run on a device (`software`: [`crate::gpu::Context::is_software`]): `Auto` becomes `Cpu`
    /// on a software rasteriser and `Vulkan` on a GPU; `Cpu` and `Vulkan` stay as asked.
    pub fn resolve(self, software: bool) -> Backend {
        match self {
            Backend::Auto if software => Backend::Cpu,
            Backend::Auto => Backend::Vulkan,
            other => other,
        }
    }
}

/// Says that `--backend auto` chose the CPU reference on a software rasteriser.
pub(crate) fn log_software_device(device: &str) {
    tracing::info!(
        "`{device}` is a software rasteriser: rendering the person with the CPU reference, which is faster on it \
         (--backend vulkan forces the Vulkan passes)"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_backend_is_the_cpu_on_a_software_rasteriser_only() {
        assert_eq!(Backend::Auto.resolve(true), Backend::Cpu);
        assert_eq!(Backend::Auto.resolve(false), Backend::Vulkan);
        for software in [true, false] {
            assert_eq!(Backend::Cpu.resolve(software), Backend::Cpu);
            assert_eq!(Backend::Vulkan.resolve(software), Backend::Vulkan);
        }
    }
}
