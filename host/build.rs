//! Compiles `shader-crate` to SPIR-V with rust-gpu and embeds it: `cargo build` is all a user
//! runs. Also writes the module's entry-point names to `$OUT_DIR/entry_points.rs`, so a unit
//! test can check that every kernel the host names exists. And names the commit it builds
//! from for `raytrace --version` (`RAYTRACE_COMMIT`).
use spirv_builder::{Capability, ModuleResult, SpirvBuilder};
use std::path::{Path, PathBuf};
use std::process::Command;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo::rustc-env=RAYTRACE_COMMIT={}", commit());
    watch_git_head();
    let out_dir = PathBuf::from(std::env::var("OUT_DIR")?);
    // A module per entry point: a driver reads the whole module for each pipeline it makes
    // (about 20 ms each for one module of every kernel on the H100, with its shader cache
    // warm), and a render makes eight.
    let compute = SpirvBuilder::new(shader_crate(), "spirv-unknown-vulkan1.2")
        .capability(Capability::VulkanMemoryModelDeviceScope)
        .capability(Capability::Int64)
        .capability(Capability::Int64Atomics)
        .capability(Capability::GroupNonUniformBallot)
        .multimodule(true);
    let names = build_modules(compute, &out_dir, "shader_modules.rs")?;
    // The ray-tracing pipeline's module: its own target folder, so that the two builds'
    // different flags do not rebuild each other's artefacts.
    let driver = SpirvBuilder::new(shader_crate(), "spirv-unknown-vulkan1.2")
        .capability(Capability::VulkanMemoryModelDeviceScope)
        .capability(Capability::Int64)
        .capability(Capability::RayTracingKHR)
        .extension("SPV_KHR_ray_tracing")
        .shader_crate_features(["driver".to_string()])
        .target_dir_path("spirv-builder-driver");
    let driver_names = build_module(driver, &out_dir.join("driver_precise.spv"), "DRIVER_SPV_PATH")?;
    let list = |n: &[String]| n.join(", ");
    std::fs::write(
        out_dir.join("entry_points.rs"),
        format!(
            "/// Entry points of the embedded SPIR-V.\npub const ENTRY_POINTS: &[&str] = &[{}];\n/// Entry points of the driver tracer's SPIR-V.\npub const DRIVER_ENTRY_POINTS: &[&str] = &[{}];\n",
            list(&names),
            list(&driver_names)
        ),
    )?;
    Ok(())
}

fn shader_crate() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shader-crate")
}

/// Builds one module of `shader-crate`, writes it to `path` with every float operation
/// marked `NoContraction` (see [`no_contraction`]), names that file in the compile-time
/// variable `var`, and returns the module's entry points (quoted).
fn build_module(mut builder: SpirvBuilder, path: &Path, var: &str) -> Result<Vec<String>, Box<dyn std::error::Error>> {
    builder.build_script.defaults = true;
    let result = builder.build()?;
    let ModuleResult::SingleModule(module) = &result.module else {
        return Err("expected a single SPIR-V module".into());
    };
    precise_copy(module, path)?;
    println!("cargo::rustc-env={var}={}", path.display());
    Ok(result.entry_points.iter().map(|e| format!("{e:?}")).collect())
}

/// Builds `shader-crate` as a module per entry point, writes each to `out_dir` with every
/// float operation marked `NoContraction` (see [`no_contraction`]), and the Rust file `list`
/// there: `SHADER_MODULES`, each entry point's name and its module's bytes. Returns the
/// entry points (quoted).
fn build_modules(
    mut builder: SpirvBuilder,
    out_dir: &Path,
    list: &str,
) -> Result<Vec<String>, Box<dyn std::error::Error>> {
    builder.build_script.defaults = true;
    let result = builder.build()?;
    let ModuleResult::MultiModule(modules) = &result.module else {
        return Err("expected a SPIR-V module per entry point".into());
    };
    let mut rows = String::new();
    for (k, (entry, module)) in modules.iter().enumerate() {
        let path = out_dir.join(format!("kernel_{k}.spv"));
        precise_copy(module, &path)?;
        rows += &format!("    ({entry:?}, include_bytes!({:?})),\n", path.display().to_string());
    }
    std::fs::write(
        out_dir.join(list),
        format!("/// Each entry point of `shader-crate` and its SPIR-V module, compiled by `host/build.rs`.\npub const SHADER_MODULES: &[(&str, &[u8])] = &[\n{rows}];\n"),
    )?;
    Ok(modules.keys().map(|e| format!("{e:?}")).collect())
}

/// Copies the SPIR-V module `from` to `to` with every float operation marked
/// `NoContraction` and without its source text and line numbers ([`strip_lines`]).
fn precise_copy(from: &Path, to: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let bytes = std::fs::read(from)?;
    let words: Vec<u32> = bytes
        .as_chunks::<4>()
        .0
        .iter()
        .map(|w| u32::from_le_bytes(*w))
        .collect();
    let precise = no_contraction(&strip_lines(&words)?)?;
    std::fs::write(to, precise.iter().flat_map(|w| w.to_le_bytes()).collect::<Vec<u8>>())?;
    Ok(())
}

/// `git ARGS` run in this crate's folder: its trimmed output, or `None` where git is missing,
/// fails (no repository) or prints nothing.
fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git")
        .arg("-C")
        .arg(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .output()
        .ok()?;
    let text = String::from_utf8(out.stdout).ok()?.trim().to_string();
    (out.status.success() && !text.is_empty()).then_some(text)
}

/// The commit being built, `abc1234 2026-11-24` (short hash, commit date), or `unknown
/// commit` where there is no git or no repository, or the repository around this folder is
/// not the project's (a copy unpacked inside another one: this build script is not in it).
fn commit() -> String {
    let ours = git(&["ls-files", "--error-unmatch", "build.rs"]).is_some();
    let hash = git(&["rev-parse", "--short", "HEAD"]);
    let date = git(&["log", "-1", "--format=%cd", "--date=short", "HEAD"]);
    match (ours, hash, date) {
        (true, Some(hash), Some(date)) => format!("{hash} {date}"),
        _ => "unknown commit".to_string(),
    }
}

/// Reruns this script when HEAD moves: on changes of git's `HEAD`, of the branch it names
/// and of `packed-refs` (where git may keep that branch), as far as they exist (a missing
/// file would rerun it on every build). Those of a worktree are found by `--git-path`.
fn watch_git_head() {
    let mut files = vec!["HEAD".to_string(), "packed-refs".to_string()];
    files.extend(git(&["symbolic-ref", "-q", "HEAD"]));
    for f in files {
        let Some(path) = git(&["rev-parse", "--path-format=absolute", "--git-path", &f]) else {
            continue;
        };
        if Path::new(&path).is_file() {
            println!("cargo::rerun-if-changed={path}");
        }
    }
}

/// OpSourceContinued, OpSource, OpLine, OpNoLine: debug information no instruction refers to.
const SOURCE_AND_LINES: [u32; 4] = [2, 3, 8, 317];

/// The module without its source text and line numbers ([`SOURCE_AND_LINES`]), which the
/// release profile's line tables put there: a third of the path tracer's module, and
/// 97% of a small kernel's (the source of every file it uses), bytes a driver reads
/// whenever it makes a pipeline.
fn strip_lines(words: &[u32]) -> Result<Vec<u32>, Box<dyn std::error::Error>> {
    if words.len() < 5 || words[0] != 0x0723_0203 {
        return Err("not a little-endian SPIR-V module".into());
    }
    let mut out = words[..5].to_vec();
    let mut i = 5;
    while i < words.len() {
        let (count, op) = ((words[i] >> 16) as usize, words[i] & 0xffff);
        if count == 0 || i + count > words.len() {
            return Err(format!("malformed SPIR-V instruction at word {i}").into());
        }
        if !SOURCE_AND_LINES.contains(&op) {
            out.extend_from_slice(&words[i..i + count]);
        }
        i += count;
    }
    Ok(out)
}

/// SPIR-V opcodes and operands `no_contraction` reads and writes.
const OP_EXT_INST_IMPORT: u32 = 11;
const OP_EXT_INST: u32 = 12;
const OP_DECORATE: u32 = 71;
const ANNOTATIONS: [u32; 8] = [71, 72, 73, 74, 75, 332, 5632, 5633];
/// OpFAdd, OpFSub, OpFMul, OpFDiv, OpFRem, OpFMod, OpVectorTimesScalar, OpDot. Not OpFNegate:
/// a negation is exact, and marked it stayed an instruction of its own in NVIDIA's code where
/// the multiply-add that reads it can negate its operand for free.
const FLOAT_ARITHMETIC: [u32; 8] = [129, 131, 133, 136, 140, 141, 142, 148];
const NO_CONTRACTION: u32 = 42;
const GLSL_FMA: u32 = 50;

/// The module with every floating-point arithmetic instruction (and GLSL `Fma`) decorated
/// `NoContraction`. Without it a Vulkan driver may fuse, reorder and simplify float
/// arithmetic as if it were exact (Mesa folds `(a + b) - a` to `b`), which breaks the
/// error-free sums and products of the sphere test and any bit-exact agreement with the CPU
/// executor. rust-gpu has no way to emit the decoration itself.
fn no_contraction(words: &[u32]) -> Result<Vec<u32>, Box<dyn std::error::Error>> {
    if words.len() < 5 || words[0] != 0x0723_0203 {
        return Err("not a little-endian SPIR-V module".into());
    }
    let mut glsl = None;
    let mut targets = Vec::new();
    let mut after_annotations = None;
    let mut i = 5;
    while i < words.len() {
        let (count, op) = ((words[i] >> 16) as usize, words[i] & 0xffff);
        if count == 0 || i + count > words.len() {
            return Err(format!("malformed SPIR-V instruction at word {i}").into());
        }
        let inst = &words[i..i + count];
        if op == OP_EXT_INST_IMPORT
            && inst[2..]
                .iter()
                .flat_map(|w| w.to_le_bytes())
                .take(12)
                .eq(*b"GLSL.std.450")
        {
            glsl = Some(inst[1]);
        }
        if ANNOTATIONS.contains(&op) {
            after_annotations = Some(i + count);
        }
        if FLOAT_ARITHMETIC.contains(&op) || (op == OP_EXT_INST && Some(inst[3]) == glsl && inst[4] == GLSL_FMA) {
            targets.push(inst[2]);
        }
        i += count;
    }
    let at = after_annotations.ok_or("the SPIR-V module has no annotations")?;
    let mut out = words[..at].to_vec();
    for id in targets {
        out.extend([3 << 16 | OP_DECORATE, id, NO_CONTRACTION]);
    }
    out.extend_from_slice(&words[at..]);
    Ok(out)
}
