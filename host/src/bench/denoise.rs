//! `raytrace bench denoise`: what the real-time denoiser buys, in error and in time: the
//! denoiser's section of "what accuracy costs in time", a command of its own because it runs
//! several scenes along a camera path with a reference for every frame. The denoiser is
//! SVGF (Schied et al. 2017, "Spatiotemporal Variance-Guided Filtering"; `shared::denoise`).
//!
//! Per scene, along a path of `--frames` frames (the camera swinging about the vertical axis
//! through its target, the animation advancing 1/60 s a frame):
//! 1. Error: relative MSE of every frame against a converged reference of the same frame
//!    (cached as `bench accuracy`'s are) for raw 1 spp, the denoised 1 spp frame
//!    (`Denoise::EveryFrame`, frames fed in order so that the history builds up as in the
//!    viewer, whose renderer changes the seed at every restart of the accumulation), the same
//!    with the benchmark setting a seed of its own every frame, and raw N spp for N = 4, 8, ... `--max-spp`, every
//!    frame rendered afresh.
//! 2. Time: GPU timestamps per frame of each method (the trace, plus the denoiser's passes),
//!    at `--timing-size` (1920x1080) and at the error's size.
//! 3. Temporal stability: the scene's own view held still, mean absolute frame-to-frame
//!    change of the radiance shown: raw 1 spp frames, their accumulation, and the denoised
//!    frames (the denoiser kept on past the 96 spp from which the viewer shows the
//!    accumulation instead).
//! 4. Crossover: on that still view, the accumulated samples per pixel from which the raw
//!    accumulation's error falls below the denoised image's: what the viewer's switch from
//!    the denoised image to the accumulation (`DENOISE_UNTIL`) should be.
use crate::bench::accuracy::{cached_reference, rel_mse, References, REL_MSE_EPS};
use crate::bench::plot::{line_chart, Chart, Scale, Series};
use crate::bench::{percentile, warm};
use crate::cli::Prepared;
use crate::gpu::{denoise_ms, stage_ms, Denoise, Gpu, GpuRenderer, Kernels, DENOISE_PASSES};
use anyhow::{bail, Context, Result};
use glam::Quat;
use shared::denoise::LEVELS;
use shared::types::{Frame, Object};
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The scenes measured unless `--scenes` names others.
pub const DEFAULT_SCENES: &str = "cornell,bunny,instances";

/// Settings of `raytrace bench denoise`.
#[derive(Clone, Debug, clap::Args, serde::Serialize)]
pub struct Options {
    /// Scenes (built-in names or files).
    #[arg(long, value_delimiter = ',', default_value = DEFAULT_SCENES)]
    pub scenes: Vec<String>,
    /// Image size of the error measurements (references, raw and denoised frames).
    #[arg(long, default_value = "480x270", value_parser = crate::cli::parse_size)]
    pub size: (u32, u32),
    /// Frames of the camera path.
    #[arg(long, default_value_t = 60)]
    pub frames: usize,
    /// Swing of the camera about its target, degrees: one period of a sine of this
    /// peak-to-peak amplitude over the path, from the scene's own camera.
    #[arg(long, default_value_t = 40.0)]
    pub orbit_deg: f32,
    /// Largest N of the raw N-spp frames (1, then powers of two from 4).
    #[arg(long, default_value_t = 256)]
    pub max_spp: u32,
    /// Samples per pixel of every reference frame of the path (at least 4 times --max-spp).
    #[arg(long, default_value_t = 2048)]
    pub reference_spp: u32,
    /// Frames of the still view whose frame-to-frame change is measured.
    #[arg(long, default_value_t = 60)]
    pub still_frames: usize,
    /// Most samples per pixel the still view accumulates looking for the crossover (its
    /// reference has 4 times as many, or --reference-spp where that is more).
    #[arg(long, default_value_t = 1024)]
    pub crossover_spp: u32,
    /// Maximum path depth instead of the scene's.
    #[arg(long)]
    pub depth: Option<u32>,
    /// Image size of the timed frames.
    #[arg(long, default_value = "1920x1080", value_parser = crate::cli::parse_size)]
    pub timing_size: (u32, u32),
    /// Timed frames of raw 1 spp and of the denoised frames at --timing-size (median).
    #[arg(long, default_value_t = 50)]
    pub timing_frames: usize,
    /// Timed frames of each raw N-spp method, N > 1, at --timing-size (median).
    #[arg(long, default_value_t = 5)]
    pub timing_runs: usize,
    /// Folder of cached reference images.
    #[arg(long, default_value = "bench/cache")]
    pub cache: PathBuf,
    /// Render the references on these devices, each a share of every reference's samples as
    /// `render --devices` splits them: `all`, or indices or names separated by commas (`0,1`).
    /// The measured frames stay on the one device the benchmark runs on.
    #[arg(long)]
    pub devices: Option<String>,
}

/// One way of making a frame, measured along the path.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Method {
    pub name: String,
    /// Samples per pixel traced per frame.
    pub spp: u32,
    pub denoised: bool,
    /// Relative MSE of every frame of the path.
    pub rel_mse: Vec<f64>,
    /// Their mean.
    pub mean_rel_mse: f64,
    /// GPU ms of every frame at the error's size: trace, plus the denoiser's passes.
    pub ms: Vec<f64>,
    /// Their median.
    pub ms_p50: f64,
    /// Median GPU ms per frame at the timing size: trace, plus the denoiser's passes.
    pub timing_ms: f64,
    /// Of which the denoiser's passes (denoised methods).
    pub timing_denoise_ms: Option<f64>,
}

/// Frame-to-frame change of a still view: mean over pixels and channels of `|x_k - x_k-1|`
/// for consecutive frames `k`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Change {
    pub name: String,
    /// Change into every frame from the one before (frames 1.. of the still view).
    pub per_frame: Vec<f64>,
    /// Their mean.
    pub mean: f64,
    /// The mean over the second half of the frames (the denoiser's history built up).
    pub mean_settled: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Stability {
    /// Mean radiance of the still view's reference (pixels and channels).
    pub reference_mean: f64,
    /// Raw 1 spp frames, their accumulation, the denoised frames.
    pub series: Vec<Change>,
}

/// Errors of the still view after `spp` accumulated samples per pixel.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CrossPoint {
    pub spp: u32,
    /// The raw accumulation's relative MSE.
    pub raw_rel_mse: f64,
    /// The denoised image's (every frame's 1 spp with the history of those before).
    pub denoised_rel_mse: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Crossover {
    pub points: Vec<CrossPoint>,
    /// Accumulated spp from which the raw accumulation's error stays below the denoised
    /// image's (log-log interpolated; absent when it is not below at `--crossover-spp`).
    pub spp: Option<f64>,
    /// The renderer's switch: a still image shows its accumulation from this many samples
    /// per pixel (`DENOISE_UNTIL`, read from the renderer).
    pub denoise_until: u32,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneReport {
    pub scene: String,
    pub primitives: usize,
    pub animated: bool,
    pub max_depth: u32,
    /// Raw 1 spp, denoised, denoised with a seed per frame, raw N spp (N rising).
    pub methods: Vec<Method>,
    /// Largest raw N whose mean error is at least the denoised frames' (absent: above raw 1
    /// spp's).
    pub matches_raw_spp: Option<u32>,
    /// Raw samples per pixel with the denoised frames' mean error, log-log interpolated
    /// (absent outside 1..max spp).
    pub equivalent_spp: Option<f64>,
    /// The same two for the denoised frames with a seed per frame.
    pub matches_raw_spp_seeded: Option<u32>,
    pub equivalent_spp_seeded: Option<f64>,
    pub stability: Stability,
    pub crossover: Crossover,
    /// Median GPU ms of each of the denoiser's passes at the timing size (the a-trous levels
    /// together).
    pub denoise_passes: Vec<(String, f64)>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub date: String,
    pub device: String,
    pub command: String,
    pub options: Options,
    pub scenes: Vec<SceneReport>,
}

/// The report's file stem: `denoise-DATE-DEVICE`, with the scenes after `denoise` where
/// they are not [`DEFAULT_SCENES`] (runs of single scenes do not overwrite each other).
pub fn stem(r: &Report, device: &str) -> String {
    let scenes = r.options.scenes.join(",");
    let device = crate::bench::slug(device);
    if scenes == DEFAULT_SCENES {
        format!("denoise-{}-{device}", r.date)
    } else {
        format!("denoise-{}-{}-{device}", crate::bench::slug(&scenes), r.date)
    }
}

/// Samples per pixel of the still view's reference: 4 times the most it accumulates, or
/// the path's where that is more.
pub fn still_reference_spp(o: &Options) -> u32 {
    o.reference_spp.max(o.crossover_spp.saturating_mul(4))
}

/// `scene` at `size`, with maximum depth `depth` where given, its own settings otherwise.
fn prepare(scene: &str, size: (u32, u32), depth: Option<u32>) -> Result<Prepared> {
    let size = format!("{}x{}", size.0, size.1);
    let depth = depth.map(|d| d.to_string());
    let mut args = vec!["raytrace", scene, "--size", &size];
    if let Some(d) = &depth {
        args.extend(["--depth", d]);
    }
    <crate::cli::SceneArgs as clap::Parser>::try_parse_from(args)?.prepare()
}

/// Names of the methods that are not raw N spp.
const DENOISED: &str = "denoised 1 spp";
const DENOISED_SEEDED: &str = "denoised 1 spp, seed per frame";

/// The camera's turn about its target at frame `k` of `frames`, degrees: one period of a
/// sine of peak-to-peak `sweep_deg`, 0 at frame 0.
pub fn orbit_deg(k: usize, frames: usize, sweep_deg: f32) -> f32 {
    0.5 * sweep_deg * (std::f32::consts::TAU * k as f32 / frames.max(1) as f32).sin()
}

/// One frame of the camera path: camera and settings, and the objects at its time.
struct Step {
    frame: Frame,
    objects: Vec<Object>,
}

/// The path's `frames` frames: the camera turned by [`orbit_deg`] about the axis through its
/// target along its up vector, objects placed at `k / 60` s.
fn path(p: &mut Prepared, frames: usize, sweep_deg: f32) -> Vec<Step> {
    let spec = p.scene.camera;
    let axis = spec.up.normalize();
    let mut steps = Vec::with_capacity(frames);
    for k in 0..frames {
        let turn = Quat::from_axis_angle(axis, orbit_deg(k, frames, sweep_deg).to_radians());
        p.scene.camera.position = spec.look_at + turn * (spec.position - spec.look_at);
        let camera = p.scene.frame(&p.data).camera;
        steps.push(Step {
            frame: Frame {
                camera,
                prev_camera: camera,
                ..p.frame
            },
            objects: p.scene.objects_in(&p.data, k as f32 / 60.0),
        });
    }
    p.scene.camera = spec;
    steps
}

/// Raw samples per pixel of the methods: 1, then powers of two from 4 to `max`.
pub fn raw_spps(max: u32) -> Vec<u32> {
    std::iter::once(1)
        .chain((2..32).map(|i| 1u32 << i).take_while(|&n| n <= max))
        .collect()
}

/// Accumulated samples per pixel at which the crossover is measured: 1, 2, 3, 4, 6, 8, 12,
/// ... (powers of two and halfway between), and `max`.
pub fn checkpoints(max: u32) -> Vec<u32> {
    let mut v = Vec::new();
    let mut n = 1u32;
    while n <= max {
        v.push(n);
        if n >= 2 && n + n / 2 <= max {
            v.push(n + n / 2);
        }
        n = match n.checked_mul(2) {
            Some(m) => m,
            None => break,
        };
    }
    v.push(max);
    v.sort_unstable();
    v.dedup();
    v
}

/// The largest raw N (of `(spp, error)` pairs) whose error is at least `err`.
pub fn matches_raw_spp(raw: &[(u32, f64)], err: f64) -> Option<u32> {
    raw.iter().filter(|(_, e)| *e >= err).map(|(n, _)| *n).max()
}

/// Raw samples per pixel with error `err`, log-log interpolated between the `(spp, error)`
/// pairs of `raw` (spp rising) that bracket it; `None` outside their range.
pub fn equivalent_spp(raw: &[(u32, f64)], err: f64) -> Option<f64> {
    raw.windows(2).find_map(|w| {
        let ((n0, e0), (n1, e1)) = (w[0], w[1]);
        if !(e0 >= err && err >= e1 && e0 > e1) {
            return None;
        }
        let t = (e0 / err).ln() / (e0 / e1).ln();
        Some(((n0 as f64).ln() + t * ((n1 as f64).ln() - (n0 as f64).ln())).exp())
    })
}

/// The accumulated spp from which the raw error stays below the denoised one (at every
/// later point: a firefly early on makes either curve jump), log-log interpolated between
/// the last point where it was not and the next; `None` where it is not below at the last.
pub fn crossover_spp(points: &[CrossPoint]) -> Option<f64> {
    if !points.last().is_some_and(|p| p.raw_rel_mse < p.denoised_rel_mse) {
        return None;
    }
    let Some(i) = points.iter().rposition(|p| p.raw_rel_mse >= p.denoised_rel_mse) else {
        return Some(points[0].spp as f64);
    };
    let (a, b) = (&points[i], &points[i + 1]);
    let (ra, rb) = (
        (a.raw_rel_mse / a.denoised_rel_mse).ln(),
        (b.raw_rel_mse / b.denoised_rel_mse).ln(),
    );
    let (xa, xb) = ((a.spp as f64).ln(), (b.spp as f64).ln());
    Some((xa + (xb - xa) * ra / (ra - rb)).exp())
}

/// Mean over pixels and channels of `|a - b|`.
pub fn mean_abs_change(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |k| (x[k] as f64 - y[k] as f64).abs()))
        .sum();
    sum / (3 * a.len().max(1)) as f64
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn p50(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    percentile(&v, 0.5)
}

/// A renderer for `p`, loaded with `step`, denoising by `denoise`.
fn renderer(
    gpu: &Arc<Gpu>,
    kernels: &Arc<Kernels>,
    p: &Prepared,
    step: &Step,
    denoise: Denoise,
) -> Result<GpuRenderer> {
    let mut r = GpuRenderer::new(gpu, kernels)?;
    r.set_build(p.build(1));
    r.load(&p.data, &step.frame)?;
    r.set_objects(&step.objects)?;
    r.set_denoise(denoise)?;
    Ok(r)
}

/// Renders `frame` with `objects` afresh (accumulation restarted, BVH rebuilt): `spp`
/// samples per pixel; returns the GPU timings.
fn show(r: &mut GpuRenderer, frame: &Frame, objects: &[Object], spp: u32) -> Result<Vec<(&'static str, f64)>> {
    r.set_objects(objects)?;
    r.set_frame(frame)?;
    r.render(spp, false)
}

/// Trace and denoise ms of a denoised frame's timings; an error when it was not denoised.
fn denoised_ms(t: &[(&'static str, f64)]) -> Result<(f64, f64)> {
    if denoise_ms(t) == 0.0 {
        bail!("a frame that should have been denoised was not");
    }
    Ok((stage_ms(t, "trace"), denoise_ms(t)))
}

/// `frame` with a seed of its own for path frame `k`.
fn seeded(frame: &Frame, k: usize) -> Frame {
    Frame {
        seed: frame.seed ^ 0x5bd1_e995u32.wrapping_mul(k as u32 + 1),
        ..*frame
    }
}

/// Samples per pixel from which `r` (denoising every frame, with samples accumulated)
/// shows a still image's accumulation instead: the renderer's threshold, asked of it.
fn denoise_until(r: &GpuRenderer) -> u32 {
    let have = r.samples();
    if !r.denoises_next(0) {
        return have.saturating_sub(1);
    }
    // The most samples the next frame may add and still be denoised (a monotone question).
    let (mut lo, mut hi) = (0u32, u32::MAX - have);
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if r.denoises_next(mid) {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    have + lo
}

/// A method's frames as measured along the path.
struct Measured {
    name: String,
    spp: u32,
    denoised: bool,
    rel_mse: Vec<f64>,
    ms: Vec<f64>,
}

impl Measured {
    fn new(name: &str, spp: u32, denoised: bool) -> Measured {
        Measured {
            name: name.into(),
            spp,
            denoised,
            rel_mse: Vec::new(),
            ms: Vec::new(),
        }
    }
}

/// Error and time of every method along the path at the error's size; returns them (raw 1
/// spp, denoised, denoised with a seed per frame, raw N spp).
fn errors(
    gpu: &Arc<Gpu>,
    kernels: &Arc<Kernels>,
    references: &mut References,
    p: &Prepared,
    steps: &[Step],
    spps: &[u32],
    o: &Options,
) -> Result<Vec<Measured>> {
    let first = steps.first().context("the path has no frame")?;
    let mut raw = renderer(gpu, kernels, p, first, Denoise::Off)?;
    let mut den = renderer(gpu, kernels, p, first, Denoise::EveryFrame)?;
    let mut den_seeded = renderer(gpu, kernels, p, first, Denoise::EveryFrame)?;
    let mut m = vec![
        Measured::new("raw 1 spp", 1, false),
        Measured::new(DENOISED, 1, true),
        Measured::new(DENOISED_SEEDED, 1, true),
    ];
    m.extend(
        spps[1..]
            .iter()
            .map(|&n| Measured::new(&format!("raw {n} spp"), n, false)),
    );
    for (k, step) in steps.iter().enumerate() {
        let reference = cached_reference(
            references,
            &p.data,
            &step.objects,
            &step.frame,
            &p.scene.name,
            o.reference_spp,
            &o.cache,
        )
        .with_context(|| format!("the reference of frame {k}"))?
        .pixels;
        for (i, &n) in spps.iter().enumerate() {
            raw.set_build(p.build(n));
            let t = show(&mut raw, &step.frame, &step.objects, n)?;
            let e = rel_mse(&raw.picture()?.linear(), &reference);
            let slot = &mut m[if i == 0 { 0 } else { i + 2 }];
            slot.rel_mse.push(e);
            slot.ms.push(stage_ms(&t, "trace"));
        }
        for (slot, r, frame) in [(1, &mut den, step.frame), (2, &mut den_seeded, seeded(&step.frame, k))] {
            let (trace, denoise) = denoised_ms(&show(r, &frame, &step.objects, 1)?)
                .with_context(|| format!("{} frame {k}", m[slot].name))?;
            m[slot].rel_mse.push(rel_mse(&r.picture()?.linear(), &reference));
            m[slot].ms.push(trace + denoise);
        }
        if (k + 1) % 10 == 0 || k + 1 == steps.len() {
            eprintln!(
                "{}: frame {}/{}: raw 1 spp {:.3e}, denoised {:.3e}",
                p.scene.name,
                k + 1,
                steps.len(),
                m[0].rel_mse[k],
                m[1].rel_mse[k]
            );
        }
    }
    Ok(m)
}

/// Median GPU ms per frame at the timing size of raw N spp (for each of `spps`) and of the
/// denoised frames (trace + denoise, denoise alone, each of its passes).
fn timings(gpu: &Arc<Gpu>, kernels: &Arc<Kernels>, spps: &[u32], scene: &str, o: &Options) -> Result<Timings> {
    let mut p = prepare(scene, o.timing_size, o.depth)?;
    let steps = path(&mut p, o.frames, o.orbit_deg);
    let at = |k: usize| &steps[k % steps.len()];
    let mut raw = renderer(gpu, kernels, &p, at(0), Denoise::Off)?;
    let mut k = 0;
    warm(|| {
        k += 1;
        show(&mut raw, &at(k).frame, &at(k).objects, 1).map(drop)
    })?;
    let mut raw_ms = Vec::new();
    for &n in spps {
        raw.set_build(p.build(n));
        let runs = if n == 1 { o.timing_frames } else { o.timing_runs };
        let mut ms = Vec::new();
        for k in 0..runs.max(1) {
            ms.push(stage_ms(&show(&mut raw, &at(k).frame, &at(k).objects, n)?, "trace"));
        }
        raw_ms.push(p50(ms));
    }
    drop(raw);
    let mut den = renderer(gpu, kernels, &p, at(0), Denoise::EveryFrame)?;
    let mut k = 0;
    warm(|| {
        k += 1;
        denoised_ms(&show(&mut den, &at(k).frame, &at(k).objects, 1)?).map(drop)
    })?;
    let (mut total, mut denoise) = (Vec::new(), Vec::new());
    let mut passes = vec![Vec::new(); DENOISE_PASSES.len()];
    for k in 0..o.timing_frames.max(1) {
        let timed = show(&mut den, &at(k).frame, &at(k).objects, 1)?;
        let (t, d) = denoised_ms(&timed)?;
        total.push(t + d);
        denoise.push(d);
        for (ms, label) in passes.iter_mut().zip(DENOISE_PASSES) {
            ms.push(stage_ms(&timed, label));
        }
    }
    let passes = DENOISE_PASSES
        .iter()
        .zip(passes)
        .map(|(label, ms)| (label.trim_start_matches("denoise ").to_string(), p50(ms)))
        .collect();
    Ok(Timings {
        raw_ms,
        denoised_ms: p50(total),
        denoise_ms: p50(denoise),
        passes,
    })
}

/// Median GPU ms at the timing size (see [`timings`]).
struct Timings {
    /// Trace of each raw N-spp method.
    raw_ms: Vec<f64>,
    /// Trace and denoiser of a denoised 1-spp frame.
    denoised_ms: f64,
    /// Of which the denoiser.
    denoise_ms: f64,
    /// Each of the denoiser's passes (the a-trous levels together).
    passes: Vec<(String, f64)>,
}

/// What one still frame showed: the raw renderer's accumulated sums, the frame's own
/// sample, the accumulation, the denoised image.
struct Shown {
    sums: Vec<[f32; 4]>,
    frame: Vec<[f32; 3]>,
    accumulated: Vec<[f32; 3]>,
    denoised: Vec<[f32; 3]>,
}

/// The still view (the path's first frame, the scene's own camera) rendered 1 spp a frame
/// by a raw and a denoising renderer: frame-to-frame change over `o.still_frames` frames,
/// and both errors at [`checkpoints`] up to `o.crossover_spp`.
fn still(
    gpu: &Arc<Gpu>,
    kernels: &Arc<Kernels>,
    p: &Prepared,
    step: &Step,
    reference: &[[f32; 3]],
    o: &Options,
) -> Result<(Stability, Crossover)> {
    let mut raw = renderer(gpu, kernels, p, step, Denoise::Off)?;
    let mut den = renderer(gpu, kernels, p, step, Denoise::EveryFrame)?;
    let checks = checkpoints(o.crossover_spp);
    let total = (o.still_frames as u32).max(o.crossover_spp);
    let mut until = 0;
    let mut points = Vec::new();
    let (mut one, mut acc, mut dens) = (Vec::new(), Vec::new(), Vec::new());
    let mut prev: Option<Shown> = None;
    for i in 0..total {
        raw.render(1, false)?;
        denoised_ms(&den.render(1, false)?).with_context(|| format!("still frame {i}"))?;
        if i == 0 {
            until = denoise_until(&den);
            den.set_denoise_until(u32::MAX);
        }
        let spp = i + 1;
        let watched = (i as usize) < o.still_frames;
        let checked = checks.contains(&spp);
        if !(watched || checked) {
            continue;
        }
        let r = raw.picture()?;
        let (accumulated, denoised) = (r.linear(), den.picture()?.linear());
        if checked {
            points.push(CrossPoint {
                spp,
                raw_rel_mse: rel_mse(&accumulated, reference),
                denoised_rel_mse: rel_mse(&denoised, reference),
            });
        }
        if watched {
            // This frame's own sample: the accumulated sums less those of the frame before.
            let frame: Vec<[f32; 3]> = match &prev {
                Some(p) => r
                    .accum
                    .iter()
                    .zip(&p.sums)
                    .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
                    .collect(),
                None => accumulated.clone(),
            };
            if let Some(p) = &prev {
                one.push(mean_abs_change(&frame, &p.frame));
                acc.push(mean_abs_change(&accumulated, &p.accumulated));
                dens.push(mean_abs_change(&denoised, &p.denoised));
            }
            prev = Some(Shown {
                sums: r.accum,
                frame,
                accumulated,
                denoised,
            });
        }
    }
    let change = |name: &str, per_frame: Vec<f64>| Change {
        name: name.into(),
        mean: mean(&per_frame),
        mean_settled: mean(&per_frame[per_frame.len() / 2..]),
        per_frame,
    };
    let stability = Stability {
        reference_mean: reference.iter().flatten().map(|&v| v as f64).sum::<f64>()
            / (3 * reference.len().max(1)) as f64,
        series: vec![
            change("raw 1 spp frames", one),
            change("raw accumulation", acc),
            change("denoised frames", dens),
        ],
    };
    let crossover = Crossover {
        spp: crossover_spp(&points),
        points,
        denoise_until: until,
    };
    Ok((stability, crossover))
}

fn scene_report(
    gpu: &Arc<Gpu>,
    kernels: &Arc<Kernels>,
    references: &mut References,
    scene: &str,
    o: &Options,
) -> Result<SceneReport> {
    let mut p = prepare(scene, o.size, o.depth)?;
    let steps = path(&mut p, o.frames, o.orbit_deg);
    let spps = raw_spps(o.max_spp);
    let measured = errors(gpu, kernels, references, &p, &steps, &spps, o)?;
    eprintln!("{}: the still view", p.scene.name);
    let reference = cached_reference(
        references,
        &p.data,
        &steps[0].objects,
        &steps[0].frame,
        &p.scene.name,
        still_reference_spp(o),
        &o.cache,
    )
    .context("the still view's reference")?
    .pixels;
    let (stability, crossover) = still(gpu, kernels, &p, &steps[0], &reference, o)?;
    eprintln!("{}: timing at {}x{}", p.scene.name, o.timing_size.0, o.timing_size.1);
    let timed = timings(gpu, kernels, &spps, scene, o)?;
    let (raw_ms, denoised_ms, denoise_ms) = (&timed.raw_ms, timed.denoised_ms, timed.denoise_ms);
    let methods: Vec<Method> = measured
        .into_iter()
        .map(|m| {
            let (timing_ms, timing_denoise_ms) = if m.denoised {
                (denoised_ms, Some(denoise_ms))
            } else {
                let i = spps.iter().position(|&n| n == m.spp).unwrap_or(0);
                (raw_ms[i], None)
            };
            Method {
                mean_rel_mse: mean(&m.rel_mse),
                ms_p50: p50(m.ms.clone()),
                name: m.name,
                spp: m.spp,
                denoised: m.denoised,
                rel_mse: m.rel_mse,
                ms: m.ms,
                timing_ms,
                timing_denoise_ms,
            }
        })
        .collect();
    let raw: Vec<(u32, f64)> = methods
        .iter()
        .filter(|m| !m.denoised)
        .map(|m| (m.spp, m.mean_rel_mse))
        .collect();
    let err = |name: &str| {
        methods
            .iter()
            .find(|m| m.name == name)
            .map_or(f64::NAN, |m| m.mean_rel_mse)
    };
    let (tris, spheres) = p.scene.counts();
    Ok(SceneReport {
        scene: p.scene.name.clone(),
        primitives: tris + spheres,
        animated: steps.windows(2).any(|w| w[0].objects != w[1].objects),
        max_depth: p.frame.max_depth,
        matches_raw_spp: matches_raw_spp(&raw, err(DENOISED)),
        equivalent_spp: equivalent_spp(&raw, err(DENOISED)),
        matches_raw_spp_seeded: matches_raw_spp(&raw, err(DENOISED_SEEDED)),
        equivalent_spp_seeded: equivalent_spp(&raw, err(DENOISED_SEEDED)),
        methods,
        stability,
        crossover,
        denoise_passes: timed.passes,
    })
}

/// Runs every scene of `o` and returns the report.
pub fn run(gpu: &Arc<Gpu>, o: &Options) -> Result<Report> {
    if o.frames == 0 || o.still_frames < 2 || o.max_spp == 0 || o.crossover_spp == 0 {
        bail!("--frames, --max-spp and --crossover-spp must be at least 1, --still-frames at least 2");
    }
    if o.reference_spp < 4 * o.max_spp {
        bail!(
            "--reference-spp ({}) must be at least 4 times --max-spp ({}): the reference's own noise would dominate",
            o.reference_spp,
            o.max_spp
        );
    }
    let kernels = Arc::new(Kernels::new(gpu)?);
    let mut references = References::new(gpu, &kernels, o.devices.as_deref())?;
    let mut scenes = Vec::new();
    for scene in &o.scenes {
        let report = scene_report(gpu, &kernels, &mut references, scene, o);
        scenes.push(report.with_context(|| format!("scene {scene}"))?);
    }
    Ok(Report {
        date: chrono::Local::now().format("%Y-%m-%d").to_string(),
        device: gpu.describe(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        options: o.clone(),
        scenes,
    })
}

/// Writes four plots per scene next to the report (`STEM-SCENE-error-time.png`, `-frames`,
/// `-stability`, `-crossover`) and returns their file names.
pub fn plots(r: &Report, dir: &Path, stem: &str) -> Result<Vec<String>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let o = &r.options;
    let mut names = Vec::new();
    for s in &r.scenes {
        let raw: Vec<&Method> = s.methods.iter().filter(|m| !m.denoised).collect();
        let mut error_time = vec![Series {
            name: format!("raw N spp (N = 1..{})", raw.last().map_or(1, |m| m.spp)),
            points: raw.iter().map(|m| (m.timing_ms, m.mean_rel_mse)).collect(),
        }];
        error_time.extend(s.methods.iter().filter(|m| m.denoised).map(|m| Series {
            name: m.name.clone(),
            points: vec![(m.timing_ms, m.mean_rel_mse)],
        }));
        let frames: Vec<Series> = s
            .methods
            .iter()
            .filter(|m| m.denoised || [1, 16, 32].contains(&m.spp))
            .map(|m| Series {
                name: m.name.clone(),
                points: m.rel_mse.iter().enumerate().map(|(k, &e)| (k as f64, e)).collect(),
            })
            .collect();
        let stability: Vec<Series> = s
            .stability
            .series
            .iter()
            .map(|c| Series {
                name: c.name.clone(),
                points: c
                    .per_frame
                    .iter()
                    .enumerate()
                    .map(|(k, &v)| ((k + 1) as f64, v))
                    .collect(),
            })
            .collect();
        let pts = &s.crossover.points;
        let crossover = vec![
            Series {
                name: "raw accumulation".into(),
                points: pts.iter().map(|p| (p.spp as f64, p.raw_rel_mse)).collect(),
            },
            Series {
                name: "denoised (1 spp a frame, history of the frames before)".into(),
                points: pts.iter().map(|p| (p.spp as f64, p.denoised_rel_mse)).collect(),
            },
        ];
        let titles = [
            format!("{}: mean relative MSE over the path against GPU time", s.scene),
            format!("{}: relative MSE of every frame of the path", s.scene),
            format!("{}: still view, mean |change| from the frame before", s.scene),
            format!("{}: still view, error against accumulated spp", s.scene),
        ];
        let time_label = format!(
            "GPU ms per frame at {}x{} (trace + denoise)",
            o.timing_size.0, o.timing_size.1
        );
        let charts = [
            (
                "error-time",
                &titles[0],
                time_label.as_str(),
                "relative MSE",
                Scale::Log,
                error_time,
            ),
            ("frames", &titles[1], "frame", "relative MSE", Scale::Linear, frames),
            (
                "stability",
                &titles[2],
                "frame",
                "mean absolute change",
                Scale::Linear,
                stability,
            ),
            (
                "crossover",
                &titles[3],
                "accumulated samples per pixel",
                "relative MSE",
                Scale::Log,
                crossover,
            ),
        ];
        for (what, title, x_label, y_label, x_scale, series) in charts {
            let name = format!("{stem}-{}-{what}.png", crate::bench::slug(&s.scene));
            let chart = Chart {
                title,
                x_label,
                y_label,
                x_scale,
                y_scale: Scale::Log,
            };
            line_chart(&dir.join(&name), &chart, &series, 900, 600)?;
            names.push(name);
        }
    }
    Ok(names)
}

/// An equivalent spp for the tables: the number, or where it lies outside the raw range
/// (`-`: the raw errors do not fall monotonically, fireflies).
fn equivalent_text(matches: Option<u32>, equivalent: Option<f64>, max: u32) -> String {
    match (equivalent, matches) {
        (Some(v), _) => format!("{v:.1}"),
        (None, None) => "< 1".into(),
        (None, Some(n)) if n == max => format!("> {max}"),
        (None, Some(_)) => "-".into(),
    }
}

pub fn markdown(r: &Report, plots: &[String]) -> String {
    let o = &r.options;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# The real-time denoiser: error against time\n\n- date: {}\n- device: {}\n- command: `{}`\n\
         - path: {} frames, the camera swinging {} degrees peak to peak about its target (one sine \
         period, from the scene's camera), the animation advancing 1/60 s a frame\n\
         - error: {}x{}, relative MSE (mean over pixels and channels of (x - ref)^2 / (ref^2 + \
         {REL_MSE_EPS})) of every frame against a reference of the same frame ({} spp, NEE + MIS, \
         an independent seed; cached in `{}`), averaged over the path; the still view's \
         reference has {} spp\n\
         - time: GPU timestamps at {}x{}, median of {} frames (raw N spp, N > 1: {}): the path \
         tracing, plus the denoiser's passes; the BVH rebuild, the same for every method, is not \
         counted\n\
         - denoised: every frame's own 1 spp with the reprojected history of the frames before \
         (`Denoise::EveryFrame`, as the viewer while the image moves); \"seed per frame\": the \
         same with the benchmark setting the frame's seed every frame (the renderer changes it at \
         every restart of its accumulation by itself)\n",
        r.date,
        r.device,
        r.command,
        o.frames,
        o.orbit_deg,
        o.size.0,
        o.size.1,
        o.reference_spp,
        o.cache.display(),
        still_reference_spp(o),
        o.timing_size.0,
        o.timing_size.1,
        o.timing_frames,
        o.timing_runs,
    );
    let _ = writeln!(s, "## Summary\n");
    let _ = writeln!(
        s,
        "| scene | denoise ms ({}x{}) | denoised frame ms | denoised relMSE | matches raw N spp | equivalent spp | seed per frame: relMSE / equivalent spp | flicker raw 1 spp / denoised | crossover spp (switch at) |",
        o.timing_size.0, o.timing_size.1
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    let max_raw = raw_spps(o.max_spp).last().copied().unwrap_or(1);
    for sc in &r.scenes {
        let find = |name: &str| sc.methods.iter().find(|m| m.name == name);
        let (Some(d), Some(ds)) = (find(DENOISED), find(DENOISED_SEEDED)) else {
            continue;
        };
        let flicker = |i: usize| sc.stability.series.get(i).map_or(f64::NAN, |c| c.mean_settled);
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.3} | {:.3e} | {} | {} | {:.3e} / {} | {:.3e} / {:.3e} | {} ({}) |",
            sc.scene,
            d.timing_denoise_ms.unwrap_or(f64::NAN),
            d.timing_ms,
            d.mean_rel_mse,
            sc.matches_raw_spp
                .map_or("none (above raw 1 spp)".into(), |n| n.to_string()),
            equivalent_text(sc.matches_raw_spp, sc.equivalent_spp, max_raw),
            ds.mean_rel_mse,
            equivalent_text(sc.matches_raw_spp_seeded, sc.equivalent_spp_seeded, max_raw),
            flicker(0),
            flicker(2),
            sc.crossover
                .spp
                .map_or(format!("> {}", o.crossover_spp), |v| format!("{v:.0}")),
            sc.crossover.denoise_until,
        );
    }
    let _ = writeln!(
        s,
        "\n\"matches raw N spp\": the largest N whose mean error is at least the denoised frames'; \
         \"equivalent spp\": raw samples per pixel of the same error, interpolated log-log between \
         1 and {} spp. Flicker: the still view's mean absolute change from the frame before, over its \
         second half (frames {}..{}). Crossover: the accumulated samples per pixel from which the \
         still view's raw accumulation keeps less error than the denoised image (the renderer shows \
         the accumulation from the number in brackets on).\n",
        max_raw,
        o.still_frames / 2 + 1,
        o.still_frames - 1
    );
    for sc in &r.scenes {
        let _ = writeln!(
            s,
            "## {}\n\n{} primitives, {}, maximum depth {}.\n",
            sc.scene,
            sc.primitives,
            if sc.animated { "animated" } else { "objects still" },
            sc.max_depth
        );
        let slug = crate::bench::slug(&sc.scene);
        for p in plots.iter().filter(|p| p.contains(&format!("-{slug}-"))) {
            let _ = writeln!(s, "![{p}]({p})");
        }
        let _ = writeln!(
            s,
            "\n| method | mean relMSE | first / last frame relMSE | GPU ms per frame ({}x{}) | of which denoise | GPU ms per frame ({}x{}) |\n|---|---|---|---|---|---|",
            o.timing_size.0, o.timing_size.1, o.size.0, o.size.1
        );
        for m in &sc.methods {
            let _ = writeln!(
                s,
                "| {} | {:.3e} | {:.3e} / {:.3e} | {:.3} | {} | {:.3} |",
                m.name,
                m.mean_rel_mse,
                m.rel_mse.first().copied().unwrap_or(f64::NAN),
                m.rel_mse.last().copied().unwrap_or(f64::NAN),
                m.timing_ms,
                m.timing_denoise_ms.map_or("-".into(), |d| format!("{d:.3}")),
                m.ms_p50
            );
        }
        let passes: Vec<String> = sc.denoise_passes.iter().map(|(l, ms)| format!("{l} {ms:.3}")).collect();
        let _ = writeln!(
            s,
            "\nThe denoiser's passes at {}x{} (median ms; the {LEVELS} a-trous levels together): {}.",
            o.timing_size.0,
            o.timing_size.1,
            passes.join(", ")
        );
        let st = &sc.stability;
        let _ = writeln!(
            s,
            "\nTemporal stability, the still view over {} frames (reference's mean radiance {:.4}):\n\n\
             | frames shown | mean change | second half | second half / mean radiance |\n|---|---|---|---|",
            o.still_frames, st.reference_mean
        );
        for c in &st.series {
            let _ = writeln!(
                s,
                "| {} | {:.3e} | {:.3e} | {:.3e} |",
                c.name,
                c.mean,
                c.mean_settled,
                c.mean_settled / st.reference_mean
            );
        }
        let _ = writeln!(
            s,
            "\nCrossover on the still view: raw accumulation below the denoised image from {} spp on \
             (the renderer's switch: {} spp).\n\n| accumulated spp | raw relMSE | denoised relMSE |\n|---|---|---|",
            sc.crossover
                .spp
                .map_or(format!("beyond {}", o.crossover_spp), |v| format!("{v:.0}")),
            sc.crossover.denoise_until
        );
        for p in &sc.crossover.points {
            let _ = writeln!(s, "| {} | {:.3e} | {:.3e} |", p.spp, p.raw_rel_mse, p.denoised_rel_mse);
        }
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_orbit_starts_at_the_scenes_camera_and_swings_both_ways() {
        assert_eq!(orbit_deg(0, 60, 40.0), 0.0);
        assert!((orbit_deg(15, 60, 40.0) - 20.0).abs() < 1e-4);
        assert!((orbit_deg(45, 60, 40.0) + 20.0).abs() < 1e-4);
    }

    #[test]
    fn sample_counts_of_the_methods_and_checkpoints() {
        assert_eq!(raw_spps(256), [1, 4, 8, 16, 32, 64, 128, 256]);
        assert_eq!(raw_spps(10), [1, 4, 8]);
        assert_eq!(raw_spps(1), [1]);
        assert_eq!(checkpoints(16), [1, 2, 3, 4, 6, 8, 12, 16]);
        assert_eq!(checkpoints(20), [1, 2, 3, 4, 6, 8, 12, 16, 20]);
    }

    #[test]
    fn the_denoised_error_is_placed_among_the_raw_ones() {
        // Error falling as 1 / N.
        let raw: Vec<(u32, f64)> = raw_spps(256).into_iter().map(|n| (n, 1.0 / n as f64)).collect();
        assert_eq!(matches_raw_spp(&raw, 1.0 / 20.0), Some(16));
        assert!((equivalent_spp(&raw, 1.0 / 20.0).unwrap() - 20.0).abs() < 1e-9);
        assert_eq!(matches_raw_spp(&raw, 2.0), None);
        assert_eq!(equivalent_spp(&raw, 2.0), None);
        assert_eq!(matches_raw_spp(&raw, 1e-4), Some(256));
        assert_eq!(equivalent_spp(&raw, 1e-4), None);
    }

    #[test]
    fn the_crossover_is_interpolated_where_raw_falls_below_denoised() {
        let point = |spp: u32, raw: f64, denoised: f64| CrossPoint {
            spp,
            raw_rel_mse: raw,
            denoised_rel_mse: denoised,
        };
        // Raw 1 / N against a denoised error of 1 / 48: they meet at 48.
        let pts: Vec<CrossPoint> = checkpoints(128)
            .into_iter()
            .map(|n| point(n, 1.0 / n as f64, 1.0 / 48.0 + if n == 48 { 1e-9 } else { 0.0 }))
            .collect();
        assert!((crossover_spp(&pts).unwrap() - 48.0).abs() < 1e-3);
        assert_eq!(crossover_spp(&pts[..3]), None);
        assert_eq!(crossover_spp(&[point(1, 0.1, 0.2)]), Some(1.0));
        // A jump of the denoised error at 2 spp is not the crossover; the last crossing is.
        let noisy = [
            point(1, 0.2, 0.1),
            point(2, 0.7, 2.0),
            point(4, 0.2, 0.1),
            point(8, 0.05, 0.1),
        ];
        let x = crossover_spp(&noisy).unwrap();
        assert!(x > 4.0 && x < 8.0, "{x}");
    }

    #[test]
    fn change_is_the_mean_absolute_difference() {
        let a = [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]];
        let b = [[1.0, 1.0, 5.0], [0.0, 0.0, 3.0]];
        assert!((mean_abs_change(&a, &b) - 1.0).abs() < 1e-12);
        assert_eq!(mean_abs_change(&a, &a), 0.0);
    }
}
