//! Which engine computes the person on a device: the Vulkan passes or the CPU reference (`--backend`), chosen by
//! the device at hand for `view` and for the XR eyes alike.

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
pub fn log_software_device(device: &str) {
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
