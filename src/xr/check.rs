//! `r2human xr --check`: what the installed OpenXR runtime offers, without starting a session.

use std::fmt;

use openxr as xr;

use super::{load_entry, XrContext, XrError};

/// One view configuration of the system.
#[derive(Clone, Debug)]
pub struct ViewConfigSummary {
    /// Its type ("PRIMARY_STEREO", ...).
    pub kind: String,
    /// Can the application change the field of view?
    pub fov_mutable: bool,
    /// Per view: recommended and maximum image size.
    pub views: Vec<ViewSize>,
    /// Environment blend modes offered for this configuration.
    pub blend_modes: Vec<String>,
}

/// Recommended and maximum image rectangle of one view.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ViewSize {
    /// Recommended width in pixels.
    pub recommended_width: u32,
    /// Recommended height in pixels.
    pub recommended_height: u32,
    /// Maximum width in pixels.
    pub max_width: u32,
    /// Maximum height in pixels.
    pub max_height: u32,
}

/// The head-mounted display the runtime reports.
#[derive(Clone, Debug)]
pub struct SystemSummary {
    /// System name ("Simulated HMD", ...).
    pub name: String,
    /// Vendor id.
    pub vendor_id: u32,
    /// Orientation tracking available.
    pub orientation_tracking: bool,
    /// Position tracking available.
    pub position_tracking: bool,
    /// Largest swapchain image the system takes.
    pub max_swapchain_size: (u32, u32),
    /// Most composition layers per frame.
    pub max_layer_count: u32,
    /// View configurations.
    pub view_configurations: Vec<ViewConfigSummary>,
}

/// What `r2human xr --check` prints.
#[derive(Clone, Debug)]
pub struct RuntimeReport {
    /// Runtime name.
    pub runtime_name: String,
    /// Runtime version ("25.0.0").
    pub runtime_version: String,
    /// Instance extensions offered, sorted.
    pub extensions: Vec<String>,
    /// API layers installed (e.g. the core validation layer).
    pub api_layers: Vec<String>,
    /// The headset, or why there is none.
    pub system: Result<SystemSummary, String>,
}

impl RuntimeReport {
    /// Does the runtime offer an extension?
    pub fn has_extension(&self, name: &str) -> bool {
        self.extensions.iter().any(|e| e == name)
    }
}

/// Extension names of an `ExtensionSet` (without the trailing NUL), sorted.
pub fn extension_names(set: &xr::ExtensionSet) -> Vec<String> {
    let mut names: Vec<String> = set
        .names()
        .into_iter()
        .map(|n| String::from_utf8_lossy(n.strip_suffix(&[0]).unwrap_or(n)).into_owned())
        .collect();
    names.sort();
    names.dedup();
    names
}

/// Queries the installed OpenXR runtime: loader, runtime, extensions, API layers, and (if a headset is present)
/// its view configurations and blend modes. Never panics; "nothing installed" is [`XrError::LoaderMissing`] or
/// [`XrError::RuntimeUnavailable`], whose messages say what to install.
pub fn check_runtime() -> Result<RuntimeReport, XrError> {
    let entry = load_entry()?;
    let available = entry.enumerate_extensions().xr("xrEnumerateInstanceExtensionProperties")?;
    let api_layers =
        entry.enumerate_layers().map(|layers| layers.into_iter().map(|l| l.layer_name).collect()).unwrap_or_default();
    let mut wanted = xr::ExtensionSet::default();
    // Enabling the Vulkan extension is harmless for a query and makes runtimes that gate systems on it answer.
    wanted.khr_vulkan_enable2 = available.khr_vulkan_enable2;
    wanted.mnd_headless = false;
    let instance = entry
        .create_instance(
            &xr::ApplicationInfo {
                application_name: "r2human check",
                application_version: 1,
                engine_name: "r2human",
                engine_version: 1,
                api_version: xr::Version::new(1, 0, 0),
            },
            &wanted,
            &[],
            &(),
        )
        .xr("xrCreateInstance")?;
    let props = instance.properties().xr("xrGetInstanceProperties")?;
    let system = query_system(&instance).map_err(|e| e.to_string());
    Ok(RuntimeReport {
        runtime_name: props.runtime_name,
        runtime_version: props.runtime_version.to_string(),
        extensions: extension_names(&available),
        api_layers,
        system,
    })
}

fn query_system(instance: &xr::Instance) -> Result<SystemSummary, XrError> {
    let system = instance.system(xr::FormFactor::HEAD_MOUNTED_DISPLAY).xr("xrGetSystem")?;
    let props = instance.system_properties(system).xr("xrGetSystemProperties")?;
    let configs = instance.enumerate_view_configurations(system).xr("xrEnumerateViewConfigurations")?;
    let mut view_configurations = Vec::new();
    for kind in configs {
        let fov_mutable = instance.view_configuration_properties(system, kind).map(|p| p.fov_mutable).unwrap_or(false);
        let views = instance
            .enumerate_view_configuration_views(system, kind)
            .unwrap_or_default()
            .into_iter()
            .map(|v| ViewSize {
                recommended_width: v.recommended_image_rect_width,
                recommended_height: v.recommended_image_rect_height,
                max_width: v.max_image_rect_width,
                max_height: v.max_image_rect_height,
            })
            .collect();
        let blend_modes = instance
            .enumerate_environment_blend_modes(system, kind)
            .unwrap_or_default()
            .into_iter()
            .map(blend_mode_name)
            .collect();
        view_configurations.push(ViewConfigSummary { kind: view_config_name(kind), fov_mutable, views, blend_modes });
    }
    Ok(SystemSummary {
        name: props.system_name,
        vendor_id: props.vendor_id,
        orientation_tracking: props.tracking_properties.orientation_tracking,
        position_tracking: props.tracking_properties.position_tracking,
        max_swapchain_size: (
            props.graphics_properties.max_swapchain_image_width,
            props.graphics_properties.max_swapchain_image_height,
        ),
        max_layer_count: props.graphics_properties.max_layer_count,
        view_configurations,
    })
}

/// "OPAQUE", "ADDITIVE", "ALPHA_BLEND" (or the raw number).
pub fn blend_mode_name(mode: xr::EnvironmentBlendMode) -> String {
    match mode {
        xr::EnvironmentBlendMode::OPAQUE => "OPAQUE".into(),
        xr::EnvironmentBlendMode::ADDITIVE => "ADDITIVE".into(),
        xr::EnvironmentBlendMode::ALPHA_BLEND => "ALPHA_BLEND".into(),
        other => format!("blend mode {}", other.into_raw()),
    }
}

/// "PRIMARY_MONO", "PRIMARY_STEREO", ... (or the raw number).
pub fn view_config_name(kind: xr::ViewConfigurationType) -> String {
    match kind {
        xr::ViewConfigurationType::PRIMARY_MONO => "PRIMARY_MONO".into(),
        xr::ViewConfigurationType::PRIMARY_STEREO => "PRIMARY_STEREO".into(),
        other => format!("view configuration {}", other.into_raw()),
    }
}

impl fmt::Display for RuntimeReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "OpenXR runtime: {} {}", self.runtime_name, self.runtime_version)?;
        let vk = if self.has_extension("XR_KHR_vulkan_enable2") { "yes" } else { "NO (r2human needs it)" };
        writeln!(f, "XR_KHR_vulkan_enable2: {vk}")?;
        writeln!(f, "Extensions ({}): {}", self.extensions.len(), self.extensions.join(" "))?;
        if self.api_layers.is_empty() {
            writeln!(f, "API layers: none installed")?;
        } else {
            writeln!(f, "API layers: {}", self.api_layers.join(" "))?;
        }
        match &self.system {
            Err(why) => writeln!(f, "Headset: none ({why})")?,
            Ok(s) => {
                writeln!(
                    f,
                    "Headset: {} (vendor {:#x}), tracking: orientation {}, position {}",
                    s.name, s.vendor_id, s.orientation_tracking, s.position_tracking
                )?;
                writeln!(
                    f,
                    "Max swapchain image: {}x{}, max layers: {}",
                    s.max_swapchain_size.0, s.max_swapchain_size.1, s.max_layer_count
                )?;
                for c in &s.view_configurations {
                    let views: Vec<String> = c
                        .views
                        .iter()
                        .map(|v| {
                            format!(
                                "{}x{} (max {}x{})",
                                v.recommended_width, v.recommended_height, v.max_width, v.max_height
                            )
                        })
                        .collect();
                    writeln!(
                        f,
                        "View configuration {}: {} views [{}], fov mutable: {}, blend modes: {}",
                        c.kind,
                        c.views.len(),
                        views.join(", "),
                        c.fov_mutable,
                        c.blend_modes.join(" ")
                    )?;
                }
                let ar = s
                    .view_configurations
                    .iter()
                    .any(|c| c.blend_modes.iter().any(|m| m == "ALPHA_BLEND" || m == "ADDITIVE"));
                let pass = self.has_extension("XR_FB_passthrough");
                let ar_line = match (ar, pass) {
                    (true, _) => "see-through blend mode (person over the real room)",
                    (false, true) => "XR_FB_passthrough (person over the camera feed)",
                    (false, false) => "no see-through mode: the person is shown over black (OPAQUE fallback)",
                };
                writeln!(f, "AR mode: {ar_line}")?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_readable() {
        assert_eq!(blend_mode_name(xr::EnvironmentBlendMode::ALPHA_BLEND), "ALPHA_BLEND");
        assert_eq!(view_config_name(xr::ViewConfigurationType::PRIMARY_STEREO), "PRIMARY_STEREO");
        let mut set = xr::ExtensionSet::default();
        set.khr_vulkan_enable2 = true;
        set.ext_debug_utils = true;
        assert_eq!(extension_names(&set), vec!["XR_EXT_debug_utils", "XR_KHR_vulkan_enable2"]);
    }

    #[test]
    fn report_says_what_ar_falls_back_to() {
        let report = RuntimeReport {
            runtime_name: "Test".into(),
            runtime_version: "1.0.0".into(),
            extensions: vec!["XR_KHR_vulkan_enable2".into()],
            api_layers: vec![],
            system: Ok(SystemSummary {
                name: "HMD".into(),
                vendor_id: 1,
                orientation_tracking: true,
                position_tracking: true,
                max_swapchain_size: (4096, 4096),
                max_layer_count: 16,
                view_configurations: vec![ViewConfigSummary {
                    kind: "PRIMARY_STEREO".into(),
                    fov_mutable: false,
                    views: vec![],
                    blend_modes: vec!["OPAQUE".into()],
                }],
            }),
        };
        let text = report.to_string();
        assert!(text.contains("XR_KHR_vulkan_enable2: yes"));
        assert!(text.contains("OPAQUE fallback"), "{text}");
        let no_hmd = RuntimeReport { system: Err("no headset".into()), extensions: vec![], ..report };
        let text = no_hmd.to_string();
        assert!(text.contains("Headset: none (no headset)") && text.contains("NO (r2human needs it)"));
    }
}
