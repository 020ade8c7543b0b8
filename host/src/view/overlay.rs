//! What the viewer reports besides the picture: the title bar (fps, GPU time per stage,
//! rays/s and the switches, averaged over half a second, and whether the frame shown was
//! denoised) and the backend statistics the `I` key prints (device, scene, stage times, the
//! BVH checked by the validator, rays/s, the denoiser).
use super::window::App;
use crate::gpu::{is_denoise, stage_ms};
use crate::render::stage_totals;
use anyhow::Result;
use std::time::Instant;

/// Frame statistics since the title was last updated.
#[derive(Default)]
pub(super) struct Stats {
    since: Option<Instant>,
    frames: u32,
    /// Frames that ran the denoiser.
    denoised: u32,
    stages: Vec<(&'static str, f64)>,
}

impl App {
    pub(super) fn count_frame(&mut self) -> Result<()> {
        let denoised = self.denoised_shown();
        let st = &mut self.stats;
        let since = *st.since.get_or_insert_with(Instant::now);
        st.frames += 1;
        st.denoised += u32::from(denoised);
        for &(label, t) in &stage_totals(&self.last_timings) {
            match st.stages.iter_mut().find(|(l, _)| *l == label) {
                Some(e) => e.1 += t,
                None => st.stages.push((label, t)),
            }
        }
        let elapsed = since.elapsed().as_secs_f64();
        if elapsed < 0.5 {
            return Ok(());
        }
        let n = st.frames as f64;
        let gpu: f64 = st.stages.iter().map(|(_, t)| t).sum::<f64>() / n;
        let stage = |name: &str| st.stages.iter().find(|(l, _)| *l == name).map_or(0.0, |(_, t)| t / n);
        let (transform, trace, display) = (stage("transform"), stage("trace"), stage("display"));
        let denoise: f64 = st
            .stages
            .iter()
            .filter(|(l, _)| is_denoise(l))
            .map(|(_, t)| t / n)
            .sum();
        let build = gpu - transform - trace - display - denoise;
        // The denoiser's time per frame it ran in.
        let denoise_ms = match st.denoised {
            0 => String::new(),
            d => format!(", denoise {:.2}", denoise * n / d as f64 * 1e3),
        };
        // Twice a second: one read of the accumulation image's ray counts.
        let rays = self.renderer.rays_per_sample()? * self.traced as f64;
        let title = format!(
            "raytrace · {} · {:.1} fps · GPU {:.2} ms (transform {:.2}, build {:.2}, trace {:.2}, display {:.2}{denoise_ms}) · {:.2} Grays/s · {} spp/frame, {} spp · depth {} · NEE {} · BVH {} · {}{}",
            self.live.scene.name,
            n / elapsed,
            gpu * 1e3,
            transform * 1e3,
            build * 1e3,
            trace * 1e3,
            display * 1e3,
            rays / trace.max(1e-9) * 1e-9,
            self.spf,
            self.renderer.samples(),
            self.live.scene.settings.max_depth,
            on(self.live.scene.settings.nee),
            on(self.live.bvh),
            self.denoise_state(),
            if self.paused { " · paused" } else { "" },
        );
        if let Some(w) = &self.window {
            w.set_title(&title);
        }
        self.stats = Stats::default();
        Ok(())
    }

    pub(super) fn print_statistics(&mut self) -> Result<()> {
        let f = *self.renderer.frame();
        let d = self.live.data();
        println!("device: {}", self.gpu.describe());
        println!(
            "scene {}: {} objects, {} triangles, {} spheres, {} emissive primitives; {}x{}, {} spp accumulated",
            self.live.scene.name,
            self.live.scene.objects.len(),
            d.model_tris.len(),
            d.model_spheres.len(),
            d.lights.len(),
            f.width,
            f.height,
            self.renderer.samples()
        );
        for (label, t) in stage_totals(&self.last_timings) {
            println!("  {label:<10} {:8.3} ms", t * 1e3);
        }
        if d.instancing.is_some() {
            // The frames refit the group and the top level between builds: built afresh.
            self.renderer.rebuild_now()?;
        }
        let bvh = self.renderer.bvh()?;
        if let Some(i) = &d.instancing {
            // Two levels: built again by the CPU executor, validated, and compared bit for bit.
            let (instanced, distinct) = i.counts();
            let (meshes, placements) = crate::cpu::levels_inputs(d, i, &d.objects);
            let opts = crate::bvh::BuildOptions {
                wide: false,
                ..self.renderer.build_options()
            };
            let checked = crate::bvh::build_levels(&meshes, &placements, opts).and_then(|l| {
                crate::bvh::validate_levels(&l, &meshes, &placements)?;
                Ok(l.nodes == bvh.nodes)
            });
            match checked {
                Ok(same) => println!(
                    "two levels valid: {} instances of {distinct} distinct primitives ({instanced} instanced); \
                     the GPU's nodes, built afresh, {} the CPU executor's",
                    placements.len(),
                    if same { "equal" } else { "DIFFER from" }
                ),
                Err(e) => println!("two levels INVALID: {e}"),
            }
        } else {
            let (tris, spheres) = self.renderer.world()?;
            match crate::bvh::validate(&bvh.nodes, &bvh.parents, &tris, &spheres) {
                Ok(s) => println!("BVH valid: {s:?}"),
                Err(e) => println!("BVH INVALID: {e}"),
            }
        }
        println!(
            "denoiser {}: the last frame is {}",
            on(self.denoise),
            self.denoise_state()
        );
        let trace_ms = stage_ms(&self.last_timings, "trace");
        let rays = self.renderer.rays_per_sample()? * self.traced as f64;
        println!(
            "last frame: {:.0} rays in {trace_ms:.3} ms of tracing = {:.2} Grays/s",
            rays,
            rays / trace_ms.max(1e-6) * 1e-6
        );
        Ok(())
    }

    /// Whether the frame shown last was denoised (its submission ran the denoiser).
    pub(super) fn denoised_shown(&self) -> bool {
        self.last_timings.iter().any(|(l, _)| is_denoise(l))
    }

    /// What the frame shown last is: denoised, or the raw accumulation and why.
    fn denoise_state(&self) -> &'static str {
        if self.denoised_shown() {
            "denoised"
        } else if !self.denoise {
            "raw (denoiser off)"
        } else {
            "raw (a still image past the denoiser's samples)"
        }
    }
}

/// "on" or "off".
pub(super) fn on(b: bool) -> &'static str {
    if b {
        "on"
    } else {
        "off"
    }
}
