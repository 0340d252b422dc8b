//! Build script: compiles every GLSL shader in `shaders/` to SPIR-V with naga (glsl-in -> spv-out) into
//! `$OUT_DIR/<name>.spv`, so the binary never compiles shaders at run time and needs no shader tool installed.
//!
//! Shaders may pull in shared code with a line `#include "file.glsl"` (resolved here, one level, from
//! `shaders/`), because naga's GLSL front end has no include support. Files ending in `.glsl` are only
//! included, never compiled on their own.

use std::fs;
use std::path::{Path, PathBuf};

fn stage_of(path: &Path) -> Option<naga::ShaderStage> {
    match path.extension()?.to_str()? {
        "comp" => Some(naga::ShaderStage::Compute),
        "vert" => Some(naga::ShaderStage::Vertex),
        "frag" => Some(naga::ShaderStage::Fragment),
        _ => None,
    }
}

fn resolve_includes(dir: &Path, source: &str) -> Result<String, String> {
    let mut out = String::with_capacity(source.len());
    for line in source.lines() {
        let trimmed = line.trim_start();
        if let Some(rest) = trimmed.strip_prefix("#include") {
            let name = rest.trim().trim_matches('"');
            let path = dir.join(name);
            println!("cargo:rerun-if-changed={}", path.display());
            let text = fs::read_to_string(&path).map_err(|e| format!("cannot include {}: {e}", path.display()))?;
            out.push_str(&text);
            out.push('\n');
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    Ok(out)
}

fn compile(path: &Path, stage: naga::ShaderStage, dir: &Path) -> Result<Vec<u8>, String> {
    let raw = fs::read_to_string(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let source = resolve_includes(dir, &raw)?;
    let mut frontend = naga::front::glsl::Frontend::default();
    let module = frontend
        .parse(&naga::front::glsl::Options::from(stage), &source)
        .map_err(|e| format!("{}: GLSL parse failed:\n{}", path.display(), e.emit_to_string(&source)))?;
    let info = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
        .validate(&module)
        .map_err(|e| format!("{}: validation failed:\n{}", path.display(), e.emit_to_string(&source)))?;
    // Vulkan clip space is written directly by the vertex shaders: no y flip (naga's default is wgpu's).
    let options = naga::back::spv::Options {
        lang_version: (1, 3),
        flags: naga::back::spv::WriterFlags::LABEL_VARYINGS,
        ..Default::default()
    };
    let pipeline = naga::back::spv::PipelineOptions { shader_stage: stage, entry_point: "main".to_string() };
    let words = naga::back::spv::write_vec(&module, &info, &options, Some(&pipeline))
        .map_err(|e| format!("{}: SPIR-V output failed: {e}", path.display()))?;
    Ok(words.iter().flat_map(|w| w.to_le_bytes()).collect())
}

fn main() {
    let dir =
        PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR")).join("shaders");
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut entries: Vec<PathBuf> = fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("cannot list {}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    entries.sort();
    let mut failures = Vec::new();
    for path in entries {
        println!("cargo:rerun-if-changed={}", path.display());
        let Some(stage) = stage_of(&path) else { continue };
        match compile(&path, stage, &dir) {
            Ok(bytes) => {
                let name = path.file_name().expect("a shader file has a name").to_string_lossy().to_string();
                fs::write(out.join(format!("{name}.spv")), bytes).expect("OUT_DIR is writable");
            }
            Err(e) => failures.push(e),
        }
    }
    if !failures.is_empty() {
        panic!("shader compilation failed:\n{}", failures.join("\n"));
    }
}
