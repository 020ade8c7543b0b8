//! `raytrace bench levels`: an instanced scene's two levels on the GPU (`gpu::GpuLevels`):
//! the meshes' builds (once), the top level built again for moving instances (as every frame
//! of an animated instanced scene would), memory per instance and per distinct primitive,
//! and the GPU's levels compared with the CPU executor's, bit for bit.
use super::{percentile, warm};
use crate::bvh::{build_levels_coded, BuildOptions, MeshPrims, MortonBits, Placement};
use crate::gpu::{Gpu, GpuLevels, Kernels};
use crate::inputs::{assets_dir, generate, load_obj, Distribution};
use anyhow::{bail, Result};
use glam::{Mat3, Vec3};
use serde::Serialize;
use std::fmt::Write;
use std::sync::Arc;

#[derive(clap::Args, Clone, Debug, Serialize)]
pub struct Options {
    /// Instances of the meshes (Suzanne, the bunny, 37 mixed primitives), on a square grid.
    #[arg(long, default_value_t = 10_000)]
    pub instances: usize,
    /// Timed top-level builds (after warm-up).
    #[arg(long, default_value_t = 100)]
    pub runs: usize,
}

#[derive(Serialize)]
pub struct Report {
    pub date: String,
    pub device: String,
    pub command: String,
    pub options: Options,
    pub distinct_primitives: usize,
    pub instanced_primitives: u64,
    /// Host clock of the meshes' builds (upload, build, copy; once per scene; the pipelines
    /// made before).
    pub mesh_builds_ms: f64,
    /// GPU microseconds of a top-level build (restructured by treelets in one round,
    /// `bvh::top_build`):
    /// the instances' boxes and their bounds, the build (its nodes written in place).
    pub top_us: f64,
    pub top_p10_us: f64,
    pub top_p90_us: f64,
    /// GPU microseconds of a plain top-level build (Karras's tree and the fit, no treelets:
    /// the boxes and their bounds, the build).
    pub top_plain_us: f64,
    pub top_plain_p10_us: f64,
    pub top_plain_p90_us: f64,
    /// GPU microseconds of a top-level refit (what the frames between two builds run:
    /// `gpu::TOP_REFITS`): the instances' boxes, the refit.
    pub top_refit_us: f64,
    pub top_refit_p10_us: f64,
    pub top_refit_p90_us: f64,
    pub memory_bytes: u64,
    pub bytes_per_instance: f64,
    pub bytes_per_distinct_primitive: f64,
    pub matches_cpu: bool,
}

/// The instances at frame `frame`: a grid on the ground, each turned about the vertical by
/// its own angle plus the frame's, scaled 0.5-1.5.
fn placements(meshes: usize, count: usize, frame: u32) -> Vec<Placement> {
    let side = (count as f64).sqrt().ceil() as usize;
    (0..count)
        .map(|k| {
            let (i, j) = ((k % side) as f32, (k / side) as f32);
            let angle = k as f32 * 2.399 + frame as f32 * 0.05;
            let scale = 0.5 + (k * 7919 % 101) as f32 / 100.0;
            let m = Mat3::from_rotation_y(angle) * scale;
            let t = Vec3::new(3.0 * i, 0.0, 3.0 * j);
            let row = |r: usize| {
                let v = m.row(r);
                [v.x, v.y, v.z, t[r]]
            };
            Placement {
                mesh: k % meshes,
                object: k as u32,
                rows: [row(0), row(1), row(2)],
            }
        })
        .collect()
}

pub fn run(gpu: &Arc<Gpu>, o: &Options) -> Result<Report> {
    let kernels = Arc::new(Kernels::new(gpu)?);
    let mut meshes = Vec::new();
    for name in ["suzanne", "bunny"] {
        meshes.push(MeshPrims {
            tris: load_obj(&assets_dir().join(format!("{name}.obj")))?,
            spheres: Vec::new(),
        });
    }
    let (tris, spheres) = generate(37, Distribution::Random, true, 37);
    meshes.push(MeshPrims { tris, spheres });
    let opts = BuildOptions::lbvh(MortonBits::B30);
    let start = placements(meshes.len(), o.instances, 0);
    // The builder's pipelines made first (on first use; a cold driver cache took seconds).
    GpuLevels::new(gpu, &kernels, &meshes, &start[..start.len().min(meshes.len())], opts)?;
    let t = std::time::Instant::now();
    let mut g = GpuLevels::new(gpu, &kernels, &meshes, &start, opts)?;
    let mesh_builds_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut frame = 0;
    let mut step = |g: &mut GpuLevels| -> Result<f64> {
        frame += 1;
        let rows: Vec<_> = placements(meshes.len(), o.instances, frame)
            .iter()
            .map(|p| p.rows)
            .collect();
        g.set_transforms(&rows)?;
        g.rebuild_top()
    };
    // Refits (never built again), then builds (every frame); the last frame built.
    let timed =
        |g: &mut GpuLevels, refits: u32, step: &mut dyn FnMut(&mut GpuLevels) -> Result<f64>| -> Result<Vec<f64>> {
            g.set_top_refits(refits);
            warm(|| step(g).map(|_| ()))?;
            let mut times = Vec::with_capacity(o.runs);
            for _ in 0..o.runs {
                times.push(step(g)? * 1e3);
            }
            times.sort_by(f64::total_cmp);
            Ok(times)
        };
    let refits = timed(&mut g, u32::MAX, &mut step)?;
    g.set_top_plain(true);
    let plain = timed(&mut g, 0, &mut step)?;
    // A plain build's top level against the CPU executor's over the same boxes, coded in
    // the same bounds (the last build's).
    let coded = g.top_code_bounds()?;
    step(&mut g)?;
    let top = crate::cpu::build_coded(&g.boxes()?, &[], BuildOptions::lbvh(opts.bits), coded.as_ref()).0;
    if g.nodes()?[g.layout().top as usize..] != top.nodes[..] {
        bail!("the GPU's plain top level differs from the CPU executor's");
    }
    g.set_top_plain(false);
    let times = timed(&mut g, 0, &mut step)?;
    // A frame's levels against the CPU executor's.
    let coded = g.top_code_bounds()?;
    step(&mut g)?;
    let last = placements(meshes.len(), o.instances, frame);
    let cpu = build_levels_coded(&meshes, &last, opts, coded.as_ref()).map_err(anyhow::Error::msg)?;
    let matches_cpu = g.nodes()? == cpu.nodes && g.boxes()? == cpu.boxes;
    if !matches_cpu {
        bail!("the GPU's levels differ from the CPU executor's");
    }
    let distinct: usize = meshes.iter().map(|m| m.tris.len() + m.spheres.len()).sum();
    let instanced: u64 = last
        .iter()
        .map(|p| (meshes[p.mesh].tris.len() + meshes[p.mesh].spheres.len()) as u64)
        .sum();
    let memory = g.memory();
    let node = size_of::<shared::types::Node>() as u64;
    let bottom = (cpu.top as u64) * node
        + (cpu.tris.len() * size_of::<shared::types::Triangle>() + cpu.spheres.len() * 16) as u64;
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        device: gpu.describe(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        options: o.clone(),
        distinct_primitives: distinct,
        instanced_primitives: instanced,
        mesh_builds_ms,
        top_us: percentile(&times, 0.5),
        top_p10_us: percentile(&times, 0.1),
        top_p90_us: percentile(&times, 0.9),
        top_plain_us: percentile(&plain, 0.5),
        top_plain_p10_us: percentile(&plain, 0.1),
        top_plain_p90_us: percentile(&plain, 0.9),
        top_refit_us: percentile(&refits, 0.5),
        top_refit_p10_us: percentile(&refits, 0.1),
        top_refit_p90_us: percentile(&refits, 0.9),
        memory_bytes: memory,
        bytes_per_instance: (memory - bottom) as f64 / o.instances.max(1) as f64,
        bytes_per_distinct_primitive: bottom as f64 / distinct.max(1) as f64,
        matches_cpu,
    })
}

pub fn markdown(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Two levels: instances of meshes\n\n- date: {}\n- device: {}\n- command: `{}`\n- {} instances of 3 meshes (Suzanne, the bunny, 37 mixed primitives): {} distinct primitives, {} instanced; every run turns every instance and builds the top level again (world boxes, coded in the last build's bounds, and this build's bounds in the merge sort's runs kernel, build restructured by treelets in one round, its nodes written where the tracers read them), as the renderer does every 60th frame (the next two frames' refits restructure it again), or as a plain LBVH (Karras's tree and the fit), or refits it (world boxes, refit), as the frames between two builds do\n",
        r.date, r.device, r.command, r.options.instances, r.distinct_primitives, r.instanced_primitives
    );
    let _ = writeln!(
        s,
        "| top level built, GPU us (p10 / median / p90) | built plain | refit | meshes' builds, ms (once) | GPU memory, MB | bytes per instance | bytes per distinct primitive | GPU = CPU |\n|---|---|---|---|---|---|---|---|\n| {:.1} / {:.1} / {:.1} | {:.1} / {:.1} / {:.1} | {:.1} / {:.1} / {:.1} | {:.1} | {:.2} | {:.0} | {:.0} | {} |",
        r.top_p10_us,
        r.top_us,
        r.top_p90_us,
        r.top_plain_p10_us,
        r.top_plain_us,
        r.top_plain_p90_us,
        r.top_refit_p10_us,
        r.top_refit_us,
        r.top_refit_p90_us,
        r.mesh_builds_ms,
        r.memory_bytes as f64 / 1e6,
        r.bytes_per_instance,
        r.bytes_per_distinct_primitive,
        if r.matches_cpu { "yes" } else { "no" }
    );
    s
}
