//! `raytrace render`: rendering a prepared scene on either backend with progress, the
//! backend `auto` picks, the summary line.
use super::scene::{segments, Pairs, Prepared, SceneArgs, Tree, Treelets};
use crate::cpu::{render_cpu_samples, CpuDenoiser, CpuRender};
use crate::gpu::{Denoise, Gpu, GpuOptions, GpuRenderer, Instance, Kernels, SAMPLES_PER_DISPATCH};
use crate::picture::Picture;
use crate::render::{self, Accel, AccelChoice, Backend};
use crate::shard::{self, Shard};
use anyhow::{anyhow, ensure, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use shared::types::{Frame, FLAG_DENOISE, VARIANT_STEPPED};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Opens the GPU, or says why not.
pub fn open_gpu(opts: &GpuOptions) -> Result<(Arc<Gpu>, Arc<Kernels>)> {
    let gpu = Gpu::new(opts)?;
    let kernels = Arc::new(Kernels::new(&gpu)?);
    Ok((gpu, kernels))
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} {elapsed_precise} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// Result of one render on either backend.
pub struct Rendered {
    pub picture: Picture,
    /// Stage seconds (GPU timestamps, or CPU wall clock).
    pub timings: Vec<(&'static str, f64)>,
    pub device: String,
    /// What traced the rays (`--accel`, as resolved for the device).
    pub tracer: Accel,
}

/// Renders on the GPU in submissions of growing size, with a progress bar when it takes
/// long.
pub fn render_gpu(r: &mut GpuRenderer, p: &Prepared, quiet: bool) -> Result<Rendered> {
    render_gpu_samples(r, p, 0, p.spp, quiet)
}

/// [`render_gpu`] of samples `first..first + spp` of the frame.
fn render_gpu_samples(r: &mut GpuRenderer, p: &Prepared, first: u32, spp: u32, quiet: bool) -> Result<Rendered> {
    let timings = trace_gpu_samples(r, p, first, spp, quiet)?;
    Ok(Rendered {
        picture: r.picture()?,
        timings: render::stage_totals(&timings),
        device: r.gpu().describe(),
        tracer: r.accel(),
    })
}

/// Loads `p` into `r` and traces samples `first..first + spp` of the frame, leaving their
/// sums on the GPU; every submission's stage times.
fn trace_gpu_samples(
    r: &mut GpuRenderer,
    p: &Prepared,
    first: u32,
    spp: u32,
    quiet: bool,
) -> Result<Vec<(&'static str, f64)>> {
    load_gpu_samples(r, p, first)?;
    Ok(trace_loaded(r, spp, quiet)?.timings)
}

/// Loads `p` into `r`, its samples to start at `first`.
fn load_gpu_samples(r: &mut GpuRenderer, p: &Prepared, first: u32) -> Result<()> {
    r.set_first_sample(first);
    r.set_build(p.build(p.spp));
    r.set_group_refits(p.group_refits);
    r.set_top_refits(p.top_refits);
    r.set_accel(p.tracer(r.gpu()).0, p.driver_build)?;
    r.load(&p.data, &p.frame)?;
    r.set_denoise(if p.frame.flags & FLAG_DENOISE != 0 {
        Denoise::Accumulated
    } else {
        Denoise::Off
    })
}

/// What [`trace_loaded`] did: every submission's stage times, how many submissions, and the
/// host seconds of the first (which makes the pipelines and builds the BVH).
struct Traced {
    timings: Vec<(&'static str, f64)>,
    submissions: u32,
    first_s: f64,
}

/// Path segments ([`segments`]) a submission of samples after a frame's first holds at most:
/// about a quarter of a second of an H200's tracing (4.5 G segments a second in the closed
/// box), so that the progress bar moves and no submission runs long enough for a display
/// driver's watchdog. Each submission costs the trace time of its own (a dispatch's tail of
/// lanes finishing the longest paths, the GPU idle between submissions: 0.2 ms a submission
/// at 800x800 and depth 16, more at 1920x1080), so a frame of less work than this is traced
/// in two (H200, 800x800 at 32 spp and depth 16, against the submissions of 1, 1, 2, 4, 8
/// and 16 samples before: the closed box 75.7 -> 74.9 ms, the bunny 14.1 -> 13.4 with NEE
/// off, the Cornell box with NEE 18.6 -> 17.3; bench/NOTES.md, session 61).
const SUBMISSION_SEGMENTS: u64 = 1 << 30;

/// Seconds a submission aims at on a device too slow for [`SUBMISSION_SEGMENTS`] in it
/// (twice an H200's time for them, so that the segments decide there).
const SUBMISSION_S: f64 = 0.5;

/// Samples a submission after the first holds: [`SUBMISSION_SEGMENTS`]'s worth, fewer where
/// the first sample's trace (`first`'s stages; `first_s` host seconds where the device has no
/// timestamps) says that would take longer than [`SUBMISSION_S`]. Where the segments decide
/// (an H200's frames: they trace about twice as fast), the submissions do not depend on the
/// clock, nor do the image's bits (a dispatch sums its samples of a pixel before adding them
/// to the accumulation).
fn submission_samples(frame: &Frame, first: &[(&'static str, f64)], first_s: f64) -> u32 {
    let pixels = frame.width as u64 * frame.height as u64;
    let by_segments = SUBMISSION_SEGMENTS / segments(frame, pixels, 1).max(1);
    let trace: f64 = first.iter().filter(|t| t.0 == "trace").map(|t| t.1).sum();
    let per_sample = if trace > 0.0 { trace } else { first_s };
    let by_clock = (SUBMISSION_S / per_sample.max(1e-9)).min(u32::MAX as f64) as u64;
    by_segments.min(by_clock).clamp(1, u32::MAX as u64) as u32
}

/// Traces `spp` samples per pixel of the scene loaded in `r`: the first sample in a
/// submission of its own (with the build), the rest in submissions of
/// [`submission_samples`].
fn trace_loaded(r: &mut GpuRenderer, spp: u32, quiet: bool) -> Result<Traced> {
    let start = Instant::now();
    let mut timings = r.render(1.min(spp), true)?;
    let first_s = start.elapsed().as_secs_f64();
    let mut submissions = 1;
    let chunk = submission_samples(r.frame(), &timings, first_s);
    let bar = (!quiet).then(|| progress_bar(spp as u64, "samples"));
    while r.samples() < spp {
        let n = chunk.min(spp - r.samples());
        timings.extend(r.render(n, false)?);
        submissions += 1;
        if let Some(b) = &bar {
            b.set_position(r.samples() as u64);
        }
    }
    if let Some(b) = bar {
        if start.elapsed().as_secs_f64() > 1.0 {
            b.finish();
        } else {
            b.finish_and_clear();
        }
    }
    Ok(Traced {
        timings,
        submissions,
        first_s,
    })
}

/// Renders on the CPU executor with a progress bar over rows.
pub fn render_on_cpu(p: &Prepared, quiet: bool) -> (Rendered, CpuRender) {
    render_on_cpu_samples(p, 0, p.spp, quiet)
}

/// [`render_on_cpu`] of samples `first..first + spp` of the frame.
fn render_on_cpu_samples(p: &Prepared, first: u32, spp: u32, quiet: bool) -> (Rendered, CpuRender) {
    let bar = (!quiet).then(|| progress_bar(p.frame.height as u64, "rows"));
    let out = render_cpu_samples(
        &p.data,
        &p.data.objects,
        &p.frame,
        first,
        spp,
        p.build(p.spp),
        &|rows| {
            if let Some(b) = &bar {
                b.set_position(rows as u64);
            }
        },
    );
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let mut picture = out.picture.clone();
    if !out.guides.is_empty() {
        let d = CpuDenoiser::default().run(&p.frame, &out.guides, spp, false, false);
        picture = picture.denoised(&d);
    }
    let rendered = Rendered {
        picture,
        timings: render::stage_totals(&out.timings),
        device: format!("CPU executor ({} threads)", rayon::current_num_threads()),
        tracer: Accel::Lbvh,
    };
    (rendered, out)
}

/// The backend `--backend auto` picks, and why: the GPU, unless no device was asked for
/// (`--device`, `RAYTRACE_DEVICE`) and every Vulkan device is a CPU implementation, or there
/// is none: then the CPU executor (on 2 cores it renders the Cornell box at 32 spp in 12.6 s,
/// lavapipe in 217 s).
pub fn choose_backend(opts: &GpuOptions) -> (Backend, String) {
    let cpu = || format!("the CPU executor ({} threads)", rayon::current_num_threads());
    let pinned = opts.device.is_some() || std::env::var_os("RAYTRACE_DEVICE").is_some();
    match Gpu::list() {
        Ok(devices) if devices.is_empty() => (
            Backend::Cpu,
            format!("{}: no Vulkan device the kernels can run on", cpu()),
        ),
        Ok(devices) if !pinned && devices.iter().all(|d| d.is_cpu()) => {
            let names: Vec<_> = devices.iter().map(|d| d.name.as_str()).collect();
            (
                Backend::Cpu,
                format!(
                    "{}: the only Vulkan device ({}) runs on the CPU, where the CPU executor runs the same kernels over 10x faster (--backend gpu uses the device anyway)",
                    cpu(),
                    names.join(", ")
                ),
            )
        }
        Ok(_) => (Backend::Gpu, "GPU".into()),
        Err(e) => (Backend::Cpu, format!("{}: no Vulkan ({e:#})", cpu())),
    }
}

/// Renders samples `first..first + spp` of `p` on every device of `devices` at once (indices
/// or names, as `--device` takes them), each an equal share of consecutive samples, and adds
/// their sums in device order (the same image whichever device finishes first).
pub fn render_devices(p: &Prepared, first: u32, spp: u32, devices: &[String], opts: &GpuOptions) -> Result<Rendered> {
    let (rendered, _, closing) = render_devices_each(p, first, spp, devices, opts)?;
    closing.close();
    Ok(rendered)
}

/// Where a render on several devices spent its time, in seconds.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct DevicesTimes {
    /// Each device's name.
    pub names: Vec<String>,
    /// Each device's description and GPU time (timestamps).
    pub gpu_s: Vec<(String, f64)>,
    /// Host clock: making the instance the devices share, then of the device that took
    /// longest: opening it (device, kernels, renderer), loading the scene, tracing (until its
    /// last submission finished), reading its sums back.
    pub open_s: f64,
    /// Of `open_s`: the instance and the device; the kernels (their module and layouts);
    /// the rest is the renderer.
    pub device_s: f64,
    /// Of `device_s`: the instance; and every device's own, in device order.
    pub instance_s: f64,
    pub each_device_s: Vec<f64>,
    pub kernels_s: f64,
    pub load_s: f64,
    pub trace_s: f64,
    /// Of `trace_s`: the first submission (its pipelines made, the BVH built, one sample);
    /// and the submissions.
    pub first_s: f64,
    pub submissions: u32,
    /// The pipelines the device made, in order, with the host seconds each took.
    pub pipelines: Vec<(&'static str, f64)>,
    pub read_s: f64,
    /// Adding the devices' sums and making the display image (while the devices close).
    pub merge_s: f64,
    /// Closing the devices after the image was made ([`Closing::close`]; 0 where they stay
    /// open or have not been closed).
    pub close_s: f64,
}

/// One device's share of a render: its sums, stage times and host clock.
struct DeviceShare {
    sums: Vec<[f32; 4]>,
    timings: Vec<(&'static str, f64)>,
    name: String,
    device: String,
    opened: Opened,
    load_s: f64,
    first_s: f64,
    submissions: u32,
    pipelines: Vec<(&'static str, f64)>,
    tracer: Accel,
    trace_s: f64,
    read_s: f64,
}

/// Devices a render opened and has finished with, still to be closed: their renderers
/// and the instance they share. Closing them (some tens of milliseconds a device, in the
/// driver) need not delay the image: [`Closing::close`] them after it is made, or drop.
pub struct Closing {
    renderers: Vec<GpuRenderer>,
    _instance: Arc<Instance>,
}

impl Closing {
    /// Closes the devices, each on a thread of its own; the seconds that took.
    pub fn close(mut self) -> f64 {
        let t = Instant::now();
        std::thread::scope(|scope| {
            for r in self.renderers.drain(..) {
                scope.spawn(move || drop(r));
            }
        });
        drop(self);
        t.elapsed().as_secs_f64()
    }
}

/// Devices opened for a render on several of them, each with its renderer: kept open across
/// the frames of `render --frames`, so that each frame pays only its trace.
pub struct OpenDevices {
    renderers: Vec<GpuRenderer>,
}

/// Host seconds opening a device took: all of it, and of it the device's and the kernels'.
#[derive(Copy, Clone, Debug, Default)]
struct Opened {
    open_s: f64,
    device_s: f64,
    kernels_s: f64,
}

/// Opens `device` (an index or a name, as `--device` takes it) of `instance` with its kernels
/// and renderer; also returns the seconds that took.
fn open_device(instance: &Arc<Instance>, device: &str, opts: &GpuOptions) -> Result<(GpuRenderer, Opened)> {
    let o = GpuOptions {
        device: Some(device.to_string()),
        ..opts.clone()
    };
    let t = Instant::now();
    let gpu = Gpu::on(instance, &o).with_context(|| format!("opening device {device}"))?;
    let device_s = t.elapsed().as_secs_f64();
    let kernels = Arc::new(Kernels::new(&gpu)?);
    let kernels_s = t.elapsed().as_secs_f64() - device_s;
    let r = GpuRenderer::new(&gpu, &kernels)?;
    let open_s = t.elapsed().as_secs_f64();
    Ok((
        r,
        Opened {
            open_s,
            device_s,
            kernels_s,
        },
    ))
}

/// Opens `devices` (indices or names, as `--device` takes them) from one instance, each on a
/// thread of its own.
pub fn open_devices(devices: &[String], opts: &GpuOptions) -> Result<OpenDevices> {
    open_devices_on(&Instance::new(opts.validation, &opts.window_extensions)?, devices, opts)
}

/// [`open_devices`] from an instance open before (the one a benchmark's own device was
/// opened from, [`Gpu::shared_instance`]).
pub fn open_devices_on(instance: &Arc<Instance>, devices: &[String], opts: &GpuOptions) -> Result<OpenDevices> {
    let opened: Vec<Result<(GpuRenderer, Opened)>> = std::thread::scope(|scope| {
        let threads: Vec<_> = devices
            .iter()
            .map(|device| scope.spawn(move || open_device(instance, device, opts)))
            .collect();
        threads
            .into_iter()
            .map(|t| {
                t.join()
                    .unwrap_or_else(|_| Err(anyhow!("a device's opening thread panicked")))
            })
            .collect()
    });
    let renderers = opened
        .into_iter()
        .map(|o| o.map(|(r, _)| r))
        .collect::<Result<Vec<_>>>()?;
    Ok(OpenDevices { renderers })
}

impl OpenDevices {
    /// Renders samples `first..first + spp` of `p` on every device at once, each an equal share
    /// of consecutive samples, and adds their sums in device order (the same image whichever
    /// device finishes first). The devices stay open.
    pub fn render(&mut self, p: &Prepared, first: u32, spp: u32) -> Result<(Rendered, DevicesTimes)> {
        let load = |r: &mut GpuRenderer, first| load_gpu_samples(r, p, first);
        self.render_work(
            &Work {
                frame: &p.frame,
                load: &load,
            },
            first,
            spp,
        )
    }

    /// [`OpenDevices::render`] of any [`Work`].
    pub fn render_work(&mut self, work: &Work, first: u32, spp: u32) -> Result<(Rendered, DevicesTimes)> {
        let renderers: Vec<&mut GpuRenderer> = self.renderers.iter_mut().collect();
        let (rendered, times, _) = render_shares(renderers, &|r| Ok((r, Opened::default())), work, first, spp, 0.0)?;
        Ok((rendered, times))
    }
}

/// What each device of a render on several renders: the frame (its size, and how the summed
/// image is displayed), and how a renderer loads the scene to trace from a given first sample.
pub struct Work<'a> {
    pub frame: &'a Frame,
    pub load: &'a (dyn Fn(&mut GpuRenderer, u32) -> Result<()> + Sync),
}

/// Refuses `n` devices for `spp` samples per pixel where a device would get none (checked
/// before any device is opened).
fn ensure_shares(n: u32, spp: u32) -> Result<()> {
    ensure!(
        n <= spp,
        "{n} devices for {spp} samples per pixel: each device needs at least one sample"
    );
    Ok(())
}

/// Samples `first..first + count` of `work` on `r`: the sums, stage times and host clock.
fn render_share(r: &mut GpuRenderer, work: &Work, first: u32, count: u32) -> Result<DeviceShare> {
    let t = Instant::now();
    (work.load)(r, first)?;
    let load_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    // The memory the sums come back to is made while the GPU traces: its pages, written
    // once here (133 MB for a 4K image), are not then faulted in by the read back.
    let pixels = r.pixels();
    let (traced, sums) = std::thread::scope(|scope| {
        let memory = scope.spawn(move || {
            let mut sums = Vec::with_capacity(pixels);
            sums.resize(pixels, [0f32; 4]);
            sums
        });
        let traced = trace_loaded(r, count, true);
        (traced, memory.join())
    });
    let traced = traced?;
    let timings = render::stage_totals(&traced.timings);
    let trace_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut sums = sums.unwrap_or_else(|_| vec![[0f32; 4]; pixels]);
    // Only the sums: the display image is made once, from all devices' sums.
    r.sums_into(&mut sums)?;
    let gpu = r.gpu();
    Ok(DeviceShare {
        sums,
        timings,
        name: gpu.name.clone(),
        device: gpu.describe(),
        opened: Opened::default(),
        load_s,
        first_s: traced.first_s,
        submissions: traced.submissions,
        pipelines: r.kernels().made_log().iter().map(|(k, s)| (k.entry(), *s)).collect(),
        tracer: r.accel(),
        trace_s,
        read_s: t.elapsed().as_secs_f64(),
    })
}

/// Renders on a renderer for every item of `items`, each on a thread of its own that gets
/// its renderer from `open` (a device opened there, owned; or one open before, borrowed)
/// with the seconds that took and of them the device's; `instance_s` the instance's before.
/// Also returns the renderers, in no particular order, for the caller to close or keep.
fn render_shares<T: Send, R: std::borrow::BorrowMut<GpuRenderer> + Send>(
    items: Vec<T>,
    open: &(dyn Fn(T) -> Result<(R, Opened)> + Sync),
    work: &Work,
    first: u32,
    spp: u32,
    instance_s: f64,
) -> Result<(Rendered, DevicesTimes, Vec<R>)> {
    let n = items.len() as u32;
    ensure_shares(n, spp)?;
    let mut merge_s = 0.0;
    let mut picture = None;
    let (give, handed) = std::sync::mpsc::channel();
    let results: Vec<Result<DeviceShare>> = std::thread::scope(|scope| {
        let (done, shares) = std::sync::mpsc::channel();
        for (k, item) in items.into_iter().enumerate() {
            // The same split as shards': device k traces shard k of n of these samples.
            let share = Shard {
                index: k as u32,
                count: n,
            }
            .samples(spp);
            let done = done.clone();
            let give = give.clone();
            scope.spawn(move || {
                let mut held = None;
                let rendered = share.and_then(|(a, count)| {
                    let (r, opened) = open(item)?;
                    let r = held.insert(r).borrow_mut();
                    let name = r.gpu().name.clone();
                    let s = render_share(r, work, first + a, count)
                        .with_context(|| format!("rendering on device {k} ({name})"))?;
                    Ok(DeviceShare { opened, ..s })
                });
                // The sums go on to be added; the renderer back to the caller.
                let _ = done.send((k, rendered));
                if let Some(r) = held {
                    let _ = give.send(r);
                }
            });
        }
        drop(done);
        let mut results: Vec<Result<DeviceShare>> = (0..n)
            .map(|_| Err(anyhow!("a device's render thread panicked")))
            .collect();
        for (k, share) in shares.iter().take(n as usize) {
            results[k] = share;
        }
        if results.iter().all(|r| r.is_ok()) {
            let t = Instant::now();
            let parts = results
                .iter_mut()
                .flat_map(|r| r.as_mut().map(|s| std::mem::take(&mut s.sums)))
                .collect();
            picture = Some(shard::sum_pictures(parts, spp, work.frame));
            merge_s = t.elapsed().as_secs_f64();
        }
        results
    });
    drop(give);
    let renderers: Vec<R> = handed.into_iter().collect();
    let parts = results.into_iter().collect::<Result<Vec<_>>>()?;
    let picture = picture.context("the devices' sums were not added")?;
    // The devices ran side by side: the stage times of the slowest.
    let total = |r: &DeviceShare| r.timings.iter().map(|t| t.1).sum::<f64>();
    let slowest = parts.iter().max_by(|a, b| total(a).total_cmp(&total(b)));
    let timings = slowest.map_or(Vec::new(), |r| r.timings.clone());
    let names: Vec<String> = parts.iter().map(|r| format!("{} {}", r.device, ms(total(r)))).collect();
    // The host clock of the device that took longest.
    let host = |r: &DeviceShare| r.opened.open_s + r.load_s + r.trace_s + r.read_s;
    let last = parts.iter().max_by(|a, b| host(a).total_cmp(&host(b)));
    let (opened, load_s, trace_s, read_s, first_s, submissions, pipelines) = last.map_or(Default::default(), |r| {
        (
            r.opened,
            r.load_s,
            r.trace_s,
            r.read_s,
            r.first_s,
            r.submissions,
            r.pipelines.clone(),
        )
    });
    let times = DevicesTimes {
        names: parts.iter().map(|r| r.name.clone()).collect(),
        gpu_s: parts.iter().map(|r| (r.device.clone(), total(r))).collect(),
        open_s: instance_s + opened.open_s,
        device_s: instance_s + opened.device_s,
        instance_s,
        each_device_s: parts.iter().map(|r| r.opened.device_s).collect(),
        kernels_s: opened.kernels_s,
        load_s,
        trace_s,
        first_s,
        submissions,
        pipelines,
        read_s,
        merge_s,
        close_s: 0.0,
    };
    let rendered = Rendered {
        picture,
        timings,
        device: format!("{n} device{}: {}", if n == 1 { "" } else { "s" }, names.join(", ")),
        // Every device resolves `--accel` alike where the devices are alike.
        tracer: parts.first().map_or(Accel::Lbvh, |r| r.tracer),
    };
    Ok((rendered, times, renderers))
}

/// [`render_devices`], and where its time went: the devices opened and rendered on; and the
/// devices, to be closed.
pub fn render_devices_each(
    p: &Prepared,
    first: u32,
    spp: u32,
    devices: &[String],
    opts: &GpuOptions,
) -> Result<(Rendered, DevicesTimes, Closing)> {
    ensure_shares(devices.len() as u32, spp)?;
    // Each device opened on the thread that renders on it: none waits for the others to open.
    let t = Instant::now();
    let instance = Instance::new(opts.validation, &opts.window_extensions)?;
    let instance_s = t.elapsed().as_secs_f64();
    let items: Vec<&str> = devices.iter().map(String::as_str).collect();
    let load = |r: &mut GpuRenderer, first| load_gpu_samples(r, p, first);
    let (rendered, times, renderers) = render_shares(
        items,
        &|device| open_device(&instance, device, opts),
        &Work {
            frame: &p.frame,
            load: &load,
        },
        first,
        spp,
        instance_s,
    )?;
    Ok((
        rendered,
        times,
        Closing {
            renderers,
            _instance: instance,
        },
    ))
}

/// The devices `--devices` names: `all` (every Vulkan device), or indices or names separated
/// by commas.
pub fn parse_devices(list: &str) -> Result<Vec<String>> {
    if list.trim() == "all" {
        let n = Gpu::list()?.len();
        ensure!(n > 0, "--devices all: no Vulkan device");
        return Ok((0..n).map(|i| i.to_string()).collect());
    }
    let devices: Vec<String> = list.split(',').map(|d| d.trim().to_string()).collect();
    ensure!(
        devices.iter().all(|d| !d.is_empty()),
        "--devices takes all, or device indices or names separated by commas (0,1), not {list:?}"
    );
    Ok(devices)
}

/// `--frames A..B`: frames `A` up to `B - 1` of an animation.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct FrameRange {
    pub start: u32,
    pub end: u32,
}

impl std::str::FromStr for FrameRange {
    type Err = String;

    fn from_str(s: &str) -> Result<FrameRange, String> {
        let bad = || format!("frames are A..B, frames A up to B - 1 with A < B (for example 0..120), not {s:?}");
        let (a, b) = s.split_once("..").ok_or_else(bad)?;
        let (start, end): (u32, u32) = (
            a.trim().parse().map_err(|_| bad())?,
            b.trim().parse().map_err(|_| bad())?,
        );
        if start >= end {
            return Err(bad());
        }
        Ok(FrameRange { start, end })
    }
}

/// `pattern` with its last run of `#` replaced by `frame`, zero-padded to the run's length
/// (`bunny-####.png`, frame 7: `bunny-0007.png`); an error where the file name has no `#`.
pub fn frame_path(pattern: &Path, frame: u32) -> Result<PathBuf> {
    let name = pattern
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let end = name.rfind('#').with_context(|| {
        format!(
            "{}: with --frames the output's name needs # where the frame number goes (for example frames/bunny-####.png)",
            pattern.display()
        )
    })?;
    let start = name[..end].rfind(|c| c != '#').map_or(0, |i| i + 1);
    let width = end + 1 - start;
    let name = format!("{}{frame:0width$}{}", &name[..start], &name[end + 1..]);
    Ok(pattern.with_file_name(name))
}

/// How `render` traces: one GPU, several, or the CPU executor.
enum Engine {
    Gpu(Box<GpuRenderer>),
    /// The devices, opened by the first frame and kept for the rest.
    Devices(Vec<String>, Option<OpenDevices>),
    Cpu,
}

/// What `render_command` does besides the scene: where to write, which samples, where.
pub struct RenderJob<'a> {
    pub backend: Backend,
    /// Output file (a pattern with `#` for frames).
    pub out: Option<PathBuf>,
    pub shard: Option<Shard>,
    /// `--devices`.
    pub devices: Option<&'a str>,
    /// `--frames` and the frames per second of their animation times.
    pub frames: Option<FrameRange>,
    pub fps: f32,
}

impl RenderJob<'_> {
    /// One frame to `out`, as `render FILE` without options.
    pub fn to(out: Option<PathBuf>) -> RenderJob<'static> {
        RenderJob {
            backend: Backend::Auto,
            out,
            shard: None,
            devices: None,
            frames: None,
            fps: 30.0,
        }
    }
}

/// `raytrace render`; with `shard` only that shard's samples, written as a shard file
/// (`crate::shard`); with `devices` on several GPUs at once; with `frames` every frame of
/// the range at times `--time + k / fps`, each to its own file. Returns the last file written.
pub fn render_command(args: &SceneArgs, job: &RenderJob, opts: &GpuOptions) -> Result<PathBuf> {
    let devices = job.devices.map(parse_devices).transpose()?;
    if devices.is_some() {
        ensure!(opts.device.is_none(), "--device and --devices: give one of them");
        ensure!(
            job.backend != Backend::Cpu,
            "--devices renders on GPUs: not with --backend cpu"
        );
        ensure!(
            !args.denoise,
            "--denoise does not combine with --devices: each device holds the raw sums of some of the frame's samples, and the denoiser needs all of them"
        );
    }
    ensure!(
        job.fps.is_finite() && job.fps > 0.0,
        "--fps must be a positive number, not {}",
        job.fps
    );
    let mut p = args.prepare()?;
    let driver = p.accel == AccelChoice::Driver;
    ensure!(
        !(driver && job.backend == Backend::Cpu),
        "--accel driver traces with the GPU driver's acceleration structures: not with --backend cpu"
    );
    let (first, spp) = match job.shard {
        Some(s) => {
            ensure!(
                !args.denoise,
                "--denoise does not combine with --shard: a shard holds the raw sums of some of the frame's samples, and the denoiser needs all of them"
            );
            s.samples(p.spp)?
        }
        None => (0, p.spp),
    };
    if args.explain {
        println!("kernel features for {}:\n{}", p.scene.name, p.features.explain());
        let b = p.build(p.spp);
        let why = if p.tree == Tree::Auto && p.treelets == Treelets::Auto && !b.wide {
            format!(
                " (--tree auto: {} path segments a frame, {} primitives; H-PLOC from {} segments or up to {} primitives)",
                p.segments(p.spp),
                p.frame.n_prims,
                Tree::AUTO_SEGMENTS,
                Tree::AUTO_PRIMS
            )
        } else {
            String::new()
        };
        let tree = if b.wide {
            "the wide BVH (VARIANT_WIDE_BVH), collapsed from the LBVH every frame: --bvh wide".to_string()
        } else if b.builds_ploc() {
            format!("the binary BVH built by H-PLOC: --bvh binary --tree ploc{why}")
        } else if b.restructures() {
            "the binary LBVH with treelets restructured: --bvh binary, --treelets".to_string()
        } else {
            format!("the binary LBVH: --bvh binary (the default, faster on the H100){why}")
        };
        // Flattened binary trees are walked through their pairs where the build writes them
        // (`BuildOptions::pairs`) and the device's binding can hold them (`GpuLbvh::has_pairs`).
        let tree = if b.wide || p.data.instancing.is_some() {
            tree
        } else {
            let auto = if p.pairs == Pairs::Auto {
                " (--pairs auto: at every size)"
            } else {
                ""
            };
            if b.pairs {
                format!("{tree}; each node's children read as one 64-byte pair{auto} (the tree alone, VARIANT_NO_PAIRS, where a device's storage-buffer binding cannot hold both)")
            } else {
                format!("{tree}; each node read, then its children (VARIANT_NO_PAIRS: no pairs written){auto}")
            }
        };
        let driver = format!(
            "the driver's acceleration structures, the bottom level built every frame ({:?})",
            p.driver_build
        );
        match p.accel {
            AccelChoice::Lbvh => println!("BVH traced: {tree}"),
            AccelChoice::Driver => println!("rays traced by {driver} (--accel driver)"),
            AccelChoice::Auto if p.data.instancing.is_some() => println!(
                "tracer (--accel auto, a scene in two levels): {driver} where the device has ray-tracing pipelines, elsewhere {tree}; the summary line names the one taken"
            ),
            AccelChoice::Auto => println!("BVH traced (--accel auto, a flattened scene): {tree}"),
        }
        let stepped = p.accel != AccelChoice::Driver
            && p.data.instancing.is_none()
            && crate::render::tracer_features(&p.frame, b) & VARIANT_STEPPED != 0;
        if stepped {
            // As the renderer groups a full dispatch's samples (not with the denoiser's guides).
            let (pixels, n) = (p.frame.width * p.frame.height, p.spp.min(SAMPLES_PER_DISPATCH));
            let groups = match p.frame.flags & FLAG_DENOISE {
                0 => shared::path::sample_groups(pixels, n),
                _ => 1,
            };
            println!("path loop on a GPU: each lane's walk stepped in a loop of its own; lanes whose walks have ended shade together once half of their subgroup waits (VARIANT_STEPPED: paths of more than one segment, flattened, through the binary BVH, without next-event estimation; the CPU executor and lavapipe run a segment at a time)");
            if groups > 1 {
                println!("persistent dispatches hand out groups of a pixel's samples, not whole pixels, so that lanes do not end over a long tail (VARIANT_GROUPS: {groups} groups of a dispatch of {n} samples at {pixels} pixels, about {} items; each group's sums added in group order after the dispatch)", shared::path::GROUP_ITEMS);
            }
        } else {
            println!("path loop: a segment at a time, each lane's walk to its end before the subgroup shades (VARIANT_STEPPED only for paths of more than one segment, flattened, through the binary BVH, without next-event estimation)");
        }
        if p.frame.flags & FLAG_DENOISE == 0 {
            println!("display on a GPU: a frame's first samples, traced in one dispatch (real time; render's first submission), write the display image from the trace, with no clearing before and no display pass after (DISPLAY_IN_TRACE; not in sample groups nor through the shadow queue); samples added later are displayed by the display pass");
        }
    }
    let name = &p.scene.name;
    let frames_tag = if job.frames.is_some() { "-####" } else { "" };
    let out = job.out.clone().unwrap_or_else(|| match job.shard {
        Some(s) => PathBuf::from(format!("{name}{frames_tag}.shard-{}-of-{}.exr", s.index, s.count)),
        None => PathBuf::from(format!("{name}{frames_tag}.png")),
    });
    // Checked before any rendering: the names and the extension.
    let outputs: Vec<(f32, PathBuf)> = match job.frames {
        Some(r) => (r.start..r.end)
            .map(|k| Ok((args.time + k as f32 / job.fps, frame_path(&out, k)?)))
            .collect::<Result<_>>()?,
        None => vec![(args.time, out.clone())],
    };
    if job.shard.is_some() {
        ensure!(
            out.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("exr")),
            "{}: a shard is written as .exr (its radiance sums and sample count, which a PNG cannot hold)",
            out.display()
        );
    }
    let backend = match job.backend {
        Backend::Auto if devices.is_some() || driver => Backend::Gpu,
        Backend::Auto => {
            let (chosen, why) = choose_backend(opts);
            eprintln!("backend: {why}");
            chosen
        }
        b => b,
    };
    let mut engine = match (backend, devices) {
        (_, Some(list)) => Engine::Devices(list, None),
        (Backend::Gpu | Backend::Auto, None) => match open_gpu(opts) {
            Ok((gpu, kernels)) => Engine::Gpu(Box::new(GpuRenderer::new(&gpu, &kernels)?)),
            Err(e) if driver => return Err(e.context("--accel driver needs a Vulkan device")),
            Err(e) => {
                eprintln!("no usable Vulkan device ({e:#}); rendering on the CPU backend instead");
                Engine::Cpu
            }
        },
        (Backend::Cpu, None) => Engine::Cpu,
    };
    for (time, path) in &outputs {
        if job.frames.is_some() {
            p.data.objects = p.scene.objects_in(&p.data, *time);
        }
        let wall = Instant::now();
        let mut closing = None;
        let rendered = match &mut engine {
            // One frame: the devices close while the image is written. Several: they stay open.
            Engine::Devices(list, _) if outputs.len() == 1 => {
                let (rendered, _, devices) = render_devices_each(&p, first, spp, list, opts)?;
                closing = Some(devices);
                rendered
            }
            Engine::Devices(list, open) => {
                if open.is_none() {
                    ensure_shares(list.len() as u32, spp)?;
                    *open = Some(open_devices(list, opts)?);
                }
                open.as_mut().context("devices not open")?.render(&p, first, spp)?.0
            }
            Engine::Gpu(r) => render_gpu_samples(r, &p, first, spp, false)?,
            Engine::Cpu => render_on_cpu_samples(&p, first, spp, false).0,
        };
        let wall = wall.elapsed().as_secs_f64();
        let closing = closing.map(|c| std::thread::spawn(move || c.close()));
        match job.shard {
            Some(s) => {
                shard::write(path, &rendered.picture, s, first, &p)?;
                println!("shard {s}: samples {first}..{} of {} per pixel", first + spp, p.spp);
            }
            None => rendered.picture.save(path)?,
        }
        if job.frames.is_some() {
            println!("frame at {time} s:");
        }
        println!("{}", summary(&p, &rendered, wall));
        println!("wrote {}", path.display());
        if let Some(c) = closing {
            let _ = c.join();
        }
    }
    Ok(outputs.last().map(|o| o.1.clone()).unwrap_or(out))
}

/// The summary line: scene, settings, device, time per stage, rays per second.
pub fn summary(p: &Prepared, r: &Rendered, wall: f64) -> String {
    let total: f64 = r.timings.iter().map(|t| t.1).sum();
    let rays = render::rays_traced(&r.picture) as f64;
    let trace = r.timings.iter().find(|t| t.0 == "trace").map_or(total, |t| t.1);
    let stages: Vec<String> = r.timings.iter().map(|(s, t)| format!("{s} {}", ms(*t))).collect();
    format!(
        "{} {}x{}, {} spp, depth {}{}: {} on {} ({}); {:.1} M rays, {:.3} Grays/s while tracing; mean luminance {:.4}; wall clock {:.2} s",
        p.scene.name,
        p.frame.width,
        p.frame.height,
        r.picture.samples,
        p.frame.max_depth,
        match (r.tracer, p.frame.flags & shared::types::FLAG_BVH) {
            (Accel::Driver, _) => ", driver's acceleration structures",
            (Accel::Lbvh, 0) => ", brute force",
            _ => "",
        },
        ms(total),
        r.device,
        stages.join(", "),
        rays * 1e-6,
        rays / trace.max(1e-12) * 1e-9,
        r.picture.mean_luminance(),
        wall
    )
}

/// Seconds as a short string in ms or s.
pub fn ms(t: f64) -> String {
    if t >= 1.0 {
        format!("{t:.2} s")
    } else {
        format!("{:.3} ms", t * 1e3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::types::FLAG_NEE;

    #[test]
    fn submissions_hold_a_budget_of_segments_or_half_a_second() {
        let frame = |size, depth, flags| Frame {
            width: size,
            height: size,
            max_depth: depth,
            flags,
            ..Default::default()
        };
        let trace = |s| [("transform", 1e-5), ("trace", s), ("display", 1e-5)];
        // The closed box (800x800, depth 16, no NEE: 10.24M segments a sample) on an H200
        // (2.4 ms a sample): the segments decide, 104 samples a submission.
        let closed_box = frame(800, 16, 0);
        assert_eq!(submission_samples(&closed_box, &trace(2.4e-3), 0.5), 104);
        assert_eq!(submission_samples(&closed_box, &trace(2.5e-3), 0.1), 104);
        // NEE counts each segment's shadow ray: half as many.
        assert_eq!(submission_samples(&frame(800, 16, FLAG_NEE), &trace(2.4e-3), 0.5), 52);
        // A device ten times slower: half a second's samples.
        assert_eq!(submission_samples(&closed_box, &trace(24e-3), 0.5), 20);
        // No timestamps: the first submission's host seconds; never less than a sample.
        assert_eq!(submission_samples(&closed_box, &[], 0.05), 10);
        assert_eq!(submission_samples(&closed_box, &[], 3.0), 1);
        assert_eq!(submission_samples(&frame(16384, 64, FLAG_NEE), &trace(1e-3), 1.0), 1);
    }
}
