//! `raytrace compare`: one scene rendered on both backends with the same random streams, and
//! what differs: the images (CPU | GPU | difference), the BVHs, the world-space primitives and
//! the stage times.
use super::render::{ms, open_gpu, render_on_cpu, Rendered};
use super::scene::{Prepared, SceneArgs};
use crate::gpu::{Gpu, GpuOptions, GpuRenderer, Kernels};
use crate::picture;
use crate::render::{self, Accel};
use anyhow::{bail, Context, Result};
use std::path::Path;
use std::sync::Arc;

/// Outcome of `raytrace compare`.
pub struct Comparison {
    pub stats: picture::DiffStats,
    /// Same tree: child links, parents and primitive order (`None`: the GPU traced with the
    /// driver's structures, `--accel driver`, and built no BVH of the project's). The radix
    /// tree's follows the Morton codes; an H-PLOC tree's follows the boxes' bits, so it can
    /// differ where the backends' transforms round a coordinate differently (`fma`).
    pub topology_identical: Option<bool>,
    /// The GPU's BVH is the CPU executor's build over the GPU's own world-space primitives,
    /// bit for bit (nodes, parents, primitive order, wide nodes): the builder's guarantee,
    /// whatever the transforms rounded (`None`: no BVH of the project's, or two levels).
    pub same_build: Option<bool>,
    /// Same tree and bit-identical boxes.
    pub bvh_identical: bool,
    /// Largest difference between the backends' world-space coordinates, relative to the
    /// largest coordinate magnitude of the scene.
    pub world_max_error: f32,
    pub cpu: Rendered,
    pub gpu: Rendered,
}

/// Renders on both backends with the same random streams and compares them.
pub fn compare(p: &Prepared, gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, quiet: bool) -> Result<Comparison> {
    let mut r = GpuRenderer::new(gpu, kernels)?;
    let build = p.build(p.spp);
    // One submission: every sample sees the BVH built in it.
    r.set_build(build);
    let (tracer, _) = p.tracer(gpu);
    r.set_accel(tracer, p.driver_build)?;
    r.load(&p.data, &p.frame)?;
    // Built in the frame, as the CPU executor builds it (the load built the top level, which
    // the frame would refit and restructure again: `TOP_ROUNDS`).
    r.build_next();
    let timings = r.render(p.spp, true)?;
    let g = Rendered {
        picture: r.picture()?,
        timings: render::stage_totals(&timings),
        device: gpu.describe(),
        tracer,
    };
    let gpu_bvh = match tracer {
        Accel::Lbvh => Some(r.bvh()?),
        Accel::Driver => None,
    };
    let (gpu_tris, gpu_spheres) = r.world()?;
    let (c, cpu_out) = render_on_cpu(p, quiet);
    let links = |b: &crate::bvh::BuildResult| b.nodes.iter().map(|n| (n.a, n.b)).collect::<Vec<_>>();
    let topology_identical = gpu_bvh.as_ref().map(|g| {
        links(g) == links(&cpu_out.bvh)
            && g.parents == cpu_out.bvh.parents
            && g.sorted_prims == cpu_out.bvh.sorted_prims
    });
    let bvh_identical =
        topology_identical == Some(true) && gpu_bvh.as_ref().is_some_and(|g| g.nodes == cpu_out.bvh.nodes);
    let same_build = match &gpu_bvh {
        Some(g) if p.data.instancing.is_none() => {
            // The CPU render's own tree where the primitives are the same bits, else a build
            // over the GPU's.
            let same = |a: &[u8], b: &[u8]| a == b;
            let rebuilt;
            let b = if same(bytemuck::cast_slice(&gpu_tris), bytemuck::cast_slice(&cpu_out.tris))
                && same(
                    bytemuck::cast_slice(&gpu_spheres),
                    bytemuck::cast_slice(&cpu_out.spheres),
                ) {
                &cpu_out.bvh
            } else {
                rebuilt = crate::cpu::build(&gpu_tris, &gpu_spheres, build).0;
                &rebuilt
            };
            // The pairs where the GPU wrote them (`GpuLbvh::has_pairs`).
            let pairs = g.pairs.is_empty() || g.pairs == b.pairs;
            Some(
                g.nodes == b.nodes
                    && g.parents == b.parents
                    && g.sorted_prims == b.sorted_prims
                    && g.wide == b.wide
                    && pairs,
            )
        }
        _ => None,
    };
    let floats = |t: &[shared::types::Triangle], s: &[shared::types::Sphere]| -> Vec<f32> {
        let mut v: Vec<f32> = bytemuck::cast_slice(t).to_vec();
        v.extend_from_slice(bytemuck::cast_slice(s));
        v
    };
    let (on_gpu, on_cpu) = (floats(&gpu_tris, &gpu_spheres), floats(&cpu_out.tris, &cpu_out.spheres));
    let scale = on_cpu.iter().fold(f32::MIN_POSITIVE, |m, x| m.max(x.abs()));
    let world_max_error = on_gpu
        .iter()
        .zip(&on_cpu)
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()))
        / scale;
    let stats = picture::diff_stats(&c.picture, &g.picture)?;
    Ok(Comparison {
        stats,
        topology_identical,
        same_build,
        bvh_identical,
        world_max_error,
        cpu: c,
        gpu: g,
    })
}

/// `raytrace compare`: writes CPU | GPU | difference, prints the stage table; an error when
/// the images differ by more than `tolerance` (relative RMSE) or the BVHs differ.
pub fn compare_command(args: &SceneArgs, out: &Path, tolerance: f64, opts: &GpuOptions) -> Result<()> {
    let p = args.prepare()?;
    let (gpu, kernels) = open_gpu(opts).context("compare needs a Vulkan device")?;
    let c = compare(&p, &gpu, &kernels, false)?;
    let ploc = p.build(p.spp).builds_ploc();
    let mean = c.cpu.picture.mean_luminance().max(1e-6) as f32;
    picture::write_comparison(&c.cpu.picture, &c.gpu.picture, 0.5 * mean, out)?;
    println!(
        "{} {}x{}, {} spp, depth {}",
        p.scene.name, p.frame.width, p.frame.height, p.spp, p.frame.max_depth
    );
    println!("| stage | CPU ({}) | GPU ({}) |", c.cpu.device, c.gpu.device);
    println!("|---|---|---|");
    let mut stages: Vec<&str> = c.cpu.timings.iter().map(|t| t.0).collect();
    for (s, _) in &c.gpu.timings {
        if !stages.contains(s) {
            stages.push(s);
        }
    }
    let find = |r: &Rendered, s: &str| r.timings.iter().find(|t| t.0 == s).map_or("-".into(), |t| ms(t.1));
    for s in stages {
        println!("| {s} | {} | {} |", find(&c.cpu, s), find(&c.gpu, s));
    }
    if let Some(same) = c.same_build {
        println!("GPU BVH = the CPU executor's build over the GPU's world-space primitives, bit for bit: {same}");
    }
    match c.topology_identical {
        Some(same) => println!(
            "world-space primitives: largest relative difference {:.2e}; the two renders' BVH topology identical: {same}{}; boxes bit-identical: {}",
            c.world_max_error,
            if !same && ploc && c.same_build == Some(true) {
                " (an H-PLOC tree follows the boxes' bits, which the transforms rounded differently)"
            } else {
                ""
            },
            c.bvh_identical
        ),
        None => println!(
            "world-space primitives: largest relative difference {:.2e}; the GPU traced the driver's acceleration structures (--accel), the CPU the project's BVH",
            c.world_max_error
        ),
    }
    println!(
        "image difference: relative RMSE {:.4} (tolerance {tolerance}), max {:.3}, {:.2}% of pixels differ by > 5% of the mean",
        c.stats.relative_rmse,
        c.stats.max_abs,
        c.stats.differing_pixels * 100.0
    );
    println!(
        "wrote {} (CPU | GPU | |difference|, full scale = half the mean luminance)",
        out.display()
    );
    if c.same_build == Some(false) {
        bail!("the GPU's BVH differs from the CPU executor's build over the same world-space primitives");
    }
    // A radix tree follows the Morton codes, which the transforms' last bits leave alone;
    // an H-PLOC tree may differ with them.
    if c.topology_identical == Some(false) && !ploc {
        bail!("the CPU and GPU built BVHs of different topology");
    }
    if c.stats.relative_rmse > tolerance {
        bail!(
            "the images differ: relative RMSE {:.4} > tolerance {tolerance}",
            c.stats.relative_rmse
        );
    }
    Ok(())
}
