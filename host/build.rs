//! Compiles `shader-crate` to SPIR-V with rust-gpu and embeds it: `cargo build` is all a user
//! runs. Also writes the module's entry-point names to `$OUT_DIR/entry_points.rs`, so a unit
//! test can check that every kernel the host names exists.
use spirv_builder::{Capability, ModuleResult, SpirvBuilder};
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let crate_path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shader-crate");
    let mut builder = SpirvBuilder::new(crate_path, "spirv-unknown-vulkan1.2")
        .capability(Capability::VulkanMemoryModelDeviceScope)
        .capability(Capability::Int64);
    builder.build_script.defaults = true;
    builder.build_script.env_shader_spv_path = Some(true);
    let result = builder.build()?;
    if !matches!(result.module, ModuleResult::SingleModule(_)) {
        return Err("expected a single SPIR-V module".into());
    }
    let names: Vec<String> = result.entry_points.iter().map(|e| format!("{e:?}")).collect();
    let out = PathBuf::from(std::env::var("OUT_DIR")?).join("entry_points.rs");
    std::fs::write(
        out,
        format!(
            "/// Entry points of the embedded SPIR-V.\npub const ENTRY_POINTS: &[&str] = &[{}];\n",
            names.join(", ")
        ),
    )?;
    Ok(())
}
