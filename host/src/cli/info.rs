//! `raytrace info`: every Vulkan device and the CPU executor with a rough speed and the
//! backend `render` picks; with `--kernels`, the driver's statistics of every kernel.
use super::render::{choose_backend, open_gpu, render_gpu, render_on_cpu, Rendered};
use super::scene::SceneArgs;
use crate::gpu::{Gpu, GpuOptions, GpuRenderer, Kernel, Kernels};
use crate::render;
use anyhow::{bail, Result};

/// `raytrace info`: every Vulkan device and the CPU executor with a rough speed (the Cornell
/// box at 128x128, 4 spp, depth 4), and the backend `render` picks. Fails where no Vulkan
/// device opens (after printing the rest).
pub fn info_command(opts: &GpuOptions) -> Result<()> {
    let args = ["raytrace", "cornell", "--size", "128x128", "--spp", "4", "--depth", "4"];
    let p = <SceneArgs as clap::Parser>::parse_from(args).prepare()?;
    let speed = |r: &Rendered| {
        let trace: f64 = r.timings.iter().filter(|t| t.0 == "trace").map(|t| t.1).sum();
        render::rays_traced(&r.picture) as f64 / trace.max(1e-9) / 1e6
    };
    let devices = Gpu::list();
    let mut opened = None;
    match &devices {
        Ok(list) if list.is_empty() => println!("Vulkan: no device the kernels can run on"),
        Ok(list) => {
            for d in list {
                let one = GpuOptions {
                    device: Some(d.index.to_string()),
                    ..opts.clone()
                };
                let line = match open_gpu(&one).and_then(|(gpu, kernels)| {
                    let r = render_gpu(&mut GpuRenderer::new(&gpu, &kernels)?, &p, true)?;
                    Ok((gpu, r))
                }) {
                    Ok((gpu, r)) => {
                        opened.get_or_insert(gpu.describe());
                        format!("{:.0} Mrays/s", speed(&r))
                    }
                    Err(e) => format!("unusable: {e:#}"),
                };
                let sms = d.processors.map(|n| format!("; {n} SMs")).unwrap_or_default();
                println!(
                    "Vulkan device {}: {} ({}, {}; bindings up to {:.0} MB{sms}): {line}",
                    d.index,
                    d.name,
                    d.kind_name(),
                    d.driver,
                    d.max_binding as f64 / 1e6
                );
            }
        }
        Err(e) => println!("Vulkan: {e:#}"),
    }
    let (cpu, _) = render_on_cpu(&p, true);
    println!(
        "CPU executor ({} threads): {:.0} Mrays/s",
        rayon::current_num_threads(),
        speed(&cpu)
    );
    println!("(rough speeds: the Cornell box, 128x128, 4 spp, depth 4, path tracing only)");
    println!("`raytrace render` picks: {}", choose_backend(opts).1);
    match opened {
        Some(_) => Ok(()),
        None => bail!("no Vulkan device opened"),
    }
}

/// `raytrace info --kernels`: the chosen device, the driver's statistics of every kernel
/// (registers, spills...) where it offers VK_KHR_pipeline_executable_properties, and of
/// `path_trace` as specialised for the Cornell box and the bunny (what renders run).
pub fn kernels_command(opts: &GpuOptions) -> Result<()> {
    let gpu = Gpu::new(opts)?;
    println!("{}", gpu.describe());
    let k = Kernels::new(&gpu)?;
    let stats = k.statistics()?;
    if stats.is_empty() {
        println!("the driver offers no pipeline statistics");
    }
    for (entry, lines) in &stats {
        println!("{entry}: {}", lines.join(", "));
    }
    // What the renders run: the path tracer specialised to each scene's features (the
    // sixteen bunnies flattened and in two levels).
    let scenes = if stats.is_empty() {
        &[][..]
    } else {
        &["cornell", "bunny", "instances"][..]
    };
    for scene in scenes {
        let layouts: &[&str] = if *scene == "instances" {
            &["off", "on"]
        } else {
            &["off"]
        };
        for nee in [false, true] {
            for &instancing in layouts {
                let args = [
                    "raytrace",
                    scene,
                    if nee { "--spp=1" } else { "--no-nee" },
                    "--instancing",
                    instancing,
                ];
                let p = <SceneArgs as clap::Parser>::parse_from(args).prepare()?;
                let nee_name = if nee { " (NEE)" } else { "" };
                let levels = if instancing == "on" { " (two levels)" } else { "" };
                // Two levels with NEE: the shadow queue's kernels too (what frames run there).
                let queue: &[Kernel] = if nee && instancing == "on" {
                    &[
                        Kernel::PathQueue,
                        Kernel::PathQueuePersistent,
                        Kernel::ShadowResolve,
                        Kernel::ShadowResolvePersistent,
                    ]
                } else {
                    &[]
                };
                // Flattened without NEE: the stepped loop's too (frames of more than one segment).
                let stepped: &[Kernel] = if !nee && instancing == "off" {
                    &[Kernel::PathStepped, Kernel::PathSteppedPersistent]
                } else {
                    &[]
                };
                let path = [Kernel::PathTrace, Kernel::PathTracePersistent];
                for &kernel in path.iter().chain(stepped).chain(queue) {
                    let lines = k.specialised_statistics(kernel, p.frame.features)?;
                    println!("{} for {scene}{nee_name}{levels}: {}", kernel.entry(), lines.join(", "));
                }
                if !nee {
                    // The walk alone, as batches of closest-hit queries run it.
                    let lines = k.specialised_statistics(Kernel::CastRays, p.frame.features)?;
                    println!("cast_rays for {scene}{levels}: {}", lines.join(", "));
                }
            }
        }
    }
    Ok(())
}
