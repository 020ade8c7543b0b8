//! Render farms' shards (`render --shard I/N`, `raytrace merge`): the shards of a frame, merged
//! in any order, are the image one render makes; merging is deterministic; shards of another
//! render, missing or repeated shards, and impossible splits are refused with errors that name
//! them; no partial file is left under a final name.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_raytrace");

/// A small Cornell box: 48x32, 8 samples per pixel.
const SCENE: [&str; 5] = ["cornell", "--size", "48x32", "--spp", "8"];

fn run(args: &[&str]) -> (Output, String) {
    let o = Command::new(BIN).args(args).output().expect("running raytrace");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o, text)
}

fn ok(args: &[&str]) -> String {
    let (o, text) = run(args);
    assert!(o.status.success(), "raytrace {} failed:\n{text}", args.join(" "));
    text
}

fn fails(args: &[&str]) -> String {
    let (o, text) = run(args);
    assert!(
        !o.status.success(),
        "raytrace {} should have failed:\n{text}",
        args.join(" ")
    );
    text
}

fn folder(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("raytrace-shards-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&d).expect("creating a temporary folder");
    d
}

fn s(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

/// Renders `SCENE` (plus `extra`) as shard `i` of `n` into `dir`.
fn shard(dir: &Path, i: u32, n: u32, extra: &[&str]) -> PathBuf {
    let path = dir.join(format!("s{i}of{n}.exr"));
    let spec = format!("{i}/{n}");
    let mut args = vec!["render"];
    args.extend(SCENE);
    args.extend(extra);
    args.extend(["--shard", &spec, "--out", s(&path)]);
    let text = ok(&args);
    assert!(text.contains(&format!("shard {spec}: samples")), "{text}");
    path
}

fn linear(path: &Path) -> Vec<f32> {
    image::open(path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
        .into_rgb32f()
        .into_raw()
}

/// The largest difference between two linear images relative to the brightest value.
fn max_relative_difference(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len(), "image sizes differ");
    let peak = a.iter().fold(0f32, |m, &v| m.max(v.abs())).max(1e-6);
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max) / peak
}

fn png_max_byte_difference(a: &Path, b: &Path) -> u8 {
    let (a, b) = (image::open(a).unwrap().into_rgb8(), image::open(b).unwrap().into_rgb8());
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap_or(0)
}

/// Whether the GPU tests may run: a Vulkan device, or REQUIRE_VULKAN=1 (then its absence fails).
fn vulkan(test: &str) -> bool {
    let has = raytrace::gpu::Gpu::list().is_ok_and(|d| !d.is_empty());
    if !has && std::env::var_os("REQUIRE_VULKAN").is_some_and(|v| v == "1") {
        panic!("{test}: REQUIRE_VULKAN=1 but no Vulkan device");
    }
    if !has {
        eprintln!("SKIPPED {test}: no Vulkan device");
    }
    has
}

/// Renders the single run and three shards on `backend`, merges them in a shuffled order,
/// and checks the merge against the single run.
fn merged_equals_single_run(test: &str, backend: &str) {
    let dir = folder(test);
    let b = ["--backend", backend];
    let (single_exr, single_png) = (dir.join("single.exr"), dir.join("single.png"));
    for out in [&single_exr, &single_png] {
        let mut args = vec!["render"];
        args.extend(SCENE);
        args.extend(b);
        args.extend(["--out", s(out)]);
        ok(&args);
    }
    // 8 samples in 3 shards: 0..2, 2..5, 5..8.
    let shards: Vec<PathBuf> = (0..3).map(|i| shard(&dir, i, 3, &b)).collect();
    let (merged_exr, merged_png, again) = (dir.join("merged.exr"), dir.join("merged.png"), dir.join("again.exr"));
    let order = [s(&shards[2]), s(&shards[0]), s(&shards[1])];
    for out in [&merged_exr, &merged_png] {
        let mut args = vec!["merge"];
        args.extend(order);
        args.extend(["--out", s(out)]);
        let text = ok(&args);
        assert!(text.contains("merged 3 shards: 48x32, 8 spp"), "{text}");
    }
    ok(&["merge", s(&shards[0]), s(&shards[1]), s(&shards[2]), "--out", s(&again)]);

    // The same samples, summed in other groups: equal within float rounding.
    let d = max_relative_difference(&linear(&single_exr), &linear(&merged_exr));
    assert!(
        d < 1e-5,
        "{backend}: merged shards differ from the single run by {d} of the peak"
    );
    assert!(png_max_byte_difference(&single_png, &merged_png) <= 1);
    // Merging is deterministic whatever order the files are given in.
    assert_eq!(
        std::fs::read(&merged_exr).unwrap(),
        std::fs::read(&again).unwrap(),
        "two merges of the same shards differ"
    );
    // Files appear whole under their names: nothing partial is left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".partial-"))
        .collect();
    assert!(leftovers.is_empty(), "partial files left: {leftovers:?}");
}

#[test]
fn cpu_shards_merge_into_the_single_run() {
    merged_equals_single_run("cpu", "cpu");
}

#[test]
fn gpu_shards_merge_into_the_single_run() {
    if vulkan("gpu_shards_merge_into_the_single_run") {
        merged_equals_single_run("gpu", "gpu");
    }
}

/// `--devices`: the samples split across devices (here the first device opened twice, as
/// two logical devices, where a host has one), the sums added in device order.
#[test]
fn devices_split_the_samples_and_add_up_to_the_single_run() {
    if !vulkan("devices_split_the_samples_and_add_up_to_the_single_run") {
        return;
    }
    let dir = folder("devices");
    let (single, split, all) = (dir.join("single.exr"), dir.join("split.exr"), dir.join("all.exr"));
    let render = |out: &Path, extra: &[&str]| {
        let mut args = vec!["render"];
        args.extend(SCENE);
        args.extend(["--backend", "gpu"]);
        args.extend(extra);
        args.extend(["--out", s(out)]);
        ok(&args)
    };
    render(&single, &[]);
    let text = render(&split, &["--devices", "0,0"]);
    assert!(text.contains("on 2 devices: "), "{text}");
    let d = max_relative_difference(&linear(&single), &linear(&split));
    assert!(d < 1e-5, "two devices differ from one by {d} of the peak");
    render(&all, &["--devices", "all"]);
    let d = max_relative_difference(&linear(&single), &linear(&all));
    assert!(d < 1e-5, "--devices all differs from one device by {d} of the peak");

    // An animation on several devices (kept open from frame to frame): each frame is the
    // one device's render at its time.
    let scene = dir.join("orbit.toml");
    std::fs::write(&scene, ANIMATED).unwrap();
    let frames = dir.join("f-##.exr");
    let text = ok(&[
        "render",
        s(&scene),
        "--devices",
        "0,0",
        "--frames",
        "2..4",
        "--fps",
        "4",
        "--out",
        s(&frames),
    ]);
    assert_eq!(text.matches("on 2 devices: ").count(), 2, "{text}");
    let mut previous = Vec::new();
    for (k, time) in [(2, "0.5"), (3, "0.75")] {
        let at = dir.join(format!("at-{k}.exr"));
        ok(&["render", s(&scene), "--backend", "gpu", "--time", time, "--out", s(&at)]);
        let frame = linear(&dir.join(format!("f-{k:02}.exr")));
        let d = max_relative_difference(&linear(&at), &frame);
        assert!(
            d < 1e-5,
            "frame {k} on two devices differs from one device at {time} s by {d}"
        );
        assert_ne!(frame, previous, "frame {k} is the frame before");
        previous = frame;
    }

    // `bench devices` runs the same split for 1, 2, ... devices and reports the agreement.
    let results = dir.join("bench");
    ok(&[
        "bench",
        "devices",
        "--devices",
        "0,0",
        "--scene",
        "cornell",
        "--size",
        "24x16",
        "--spp",
        "4",
        "--out",
        s(&results),
    ]);
    let json = std::fs::read_dir(&results)
        .unwrap()
        .filter_map(|e| e.ok())
        .find(|e| e.path().extension().is_some_and(|x| x == "json"))
        .expect("bench devices wrote no JSON");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(json.path()).unwrap()).unwrap();
    let rows = v["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 2);
    for r in rows {
        assert!(r["max_rel_diff"].as_f64().unwrap() < 1e-5, "{r}");
        let wall = r["wall_s"].as_f64().unwrap();
        assert!(wall > 0.0, "{r}");
        // The breakdown: every part measured, and together within the wall clock.
        let t = &r["times"];
        let parts: Vec<f64> = ["open_s", "load_s", "trace_s", "read_s", "merge_s"]
            .iter()
            .map(|k| t[k].as_f64().unwrap_or_else(|| panic!("no times.{k} in {r}")))
            .collect();
        assert!(parts.iter().all(|&p| p > 0.0), "{r}");
        assert!(parts.iter().sum::<f64>() <= wall * 1.001, "{r}");
        // Within them: the first submission within the trace, the instance and the device
        // within the opening; the devices closed after the image.
        let time = |k: &str| t[k].as_f64().unwrap_or_else(|| panic!("no times.{k} in {r}"));
        assert!(time("first_s") > 0.0 && time("first_s") <= time("trace_s"), "{r}");
        assert!(
            time("device_s") <= time("open_s") && time("instance_s") <= time("device_s"),
            "{r}"
        );
        assert!(time("close_s") > 0.0, "{r}");
        assert!(t["submissions"].as_u64().is_some_and(|n| n >= 1), "{r}");
        let made = t["pipelines"].as_array().expect("pipelines");
        assert!(made.iter().any(|p| p[0] == "path_trace"), "{r}");
        // Every run's wall clock, the row's the median.
        let runs: Vec<f64> = r["runs_s"]
            .as_array()
            .expect("runs")
            .iter()
            .filter_map(|x| x.as_f64())
            .collect();
        assert_eq!(runs.len(), 3, "{r}");
        let mut sorted = runs.clone();
        sorted.sort_by(f64::total_cmp);
        assert_eq!(sorted[1], wall, "{r}");
        assert_eq!(
            t["names"].as_array().map(|a| a.len()),
            r["devices"].as_u64().map(|d| d as usize),
            "{r}"
        );
    }

    let out = dir.join("x.exr");
    let base = ["render", "cornell", "--size", "8x8", "--spp", "2", "--out", s(&out)];
    for (extra, says) in [
        (&["--devices", "0,0", "--backend", "cpu"][..], "not with --backend cpu"),
        (&["--devices", "0,,1"][..], "--devices takes all"),
        (&["--devices", "0,0,0"][..], "3 devices for 2 samples per pixel"),
        (&["--devices", "0", "--device", "0"][..], "give one of them"),
        (&["--devices", "0,99"][..], "device 99"),
    ] {
        let mut args = base.to_vec();
        args.extend(extra);
        let text = fails(&args);
        assert!(text.contains(says), "{extra:?}: {text}");
    }
}

#[test]
fn merge_refuses_what_is_not_one_frames_shards() {
    let dir = folder("refuse");
    let cpu = ["--backend", "cpu"];
    let a: Vec<PathBuf> = (0..3).map(|i| shard(&dir, i, 3, &cpu)).collect();
    let out = dir.join("out.png");
    let o = s(&out);

    let text = fails(&["merge", s(&a[0]), s(&a[2]), "--out", o]);
    assert!(text.contains("shards missing of 3: 1"), "{text}");
    let text = fails(&["merge", s(&a[0]), s(&a[1]), s(&a[1]), s(&a[2]), "--out", o]);
    assert!(text.contains("more than once: 1"), "{text}");

    // Another seed is another render: the hashes differ.
    let other = dir.join("other");
    std::fs::create_dir_all(&other).unwrap();
    let seeded = shard(&other, 1, 3, &["--backend", "cpu", "--seed", "7"]);
    let text = fails(&["merge", s(&a[0]), s(&seeded), s(&a[2]), "--out", o]);
    assert!(
        text.contains("not shards of the same render") && text.contains("hashes"),
        "{text}"
    );

    // Another split of the same render.
    let half = shard(&other, 0, 2, &cpu);
    let text = fails(&["merge", s(&a[1]), s(&half), "--out", o]);
    assert!(text.contains("shard counts differ"), "{text}");

    // Not a shard at all: a plain render's EXR, and a file that is not an EXR.
    let plain = dir.join("plain.exr");
    let mut args = vec!["render"];
    args.extend(SCENE);
    args.extend(["--backend", "cpu", "--out", s(&plain)]);
    ok(&args);
    let text = fails(&["merge", s(&plain), "--out", o]);
    assert!(text.contains("not a shard written by"), "{text}");
    let junk = dir.join("junk.exr");
    std::fs::write(&junk, b"not an image").unwrap();
    let text = fails(&["merge", s(&junk), "--out", o]);
    assert!(text.contains("junk.exr"), "{text}");
    assert!(!out.exists(), "a failed merge wrote {}", out.display());
}

#[test]
fn impossible_shards_are_refused_before_rendering() {
    let dir = folder("impossible");
    let out = dir.join("x.exr");
    let base = ["render", "cornell", "--size", "8x8", "--spp", "4", "--backend", "cpu"];
    for (spec, says) in [
        ("4/4", "0 <= I < N"),
        ("1/0", "0 <= I < N"),
        ("a/b", "0 <= I < N"),
        ("0/5", "5 shards of 4 samples per pixel"),
    ] {
        let mut args = base.to_vec();
        args.extend(["--shard", spec, "--out", s(&out)]);
        let text = fails(&args);
        assert!(text.contains(says), "--shard {spec}: {text}");
    }
    let png = dir.join("x.png");
    let mut args = base.to_vec();
    args.extend(["--shard", "0/2", "--out", s(&png)]);
    let text = fails(&args);
    assert!(text.contains("a shard is written as .exr"), "{text}");
    let mut args = base.to_vec();
    args.extend(["--shard", "0/2", "--denoise", "--out", s(&out)]);
    let text = fails(&args);
    assert!(text.contains("--denoise does not combine with --shard"), "{text}");
    assert!(!out.exists() && !png.exists());
}

/// A small animated scene: a sphere orbiting over a floor under a sky.
const ANIMATED: &str = r#"
[camera]
position = [0, 2, -6]
look_at = [0, 0.5, 0]
vfov = 40

[render]
width = 40
height = 30
spp = 4
sky = { top = [0.5, 0.7, 1.0], bottom = [1, 1, 1] }

[materials.ground]
kind = "diffuse"
albedo = [0.5, 0.5, 0.5]

[materials.red]
kind = "diffuse"
albedo = [0.8, 0.1, 0.1]

[[objects]]
name = "floor"
mesh = "builtin:quad"
material = "ground"
scale = [20, 1, 20]

[[objects]]
name = "ball"
sphere = 0.5
material = "red"

[objects.animation]
orbit = { center = [0, 0.5, 0], radius = 2, period = 2 }
"#;

/// `--frames A..B`: each frame at its own time into its own file, the same picture `--time`
/// gives; shards of a frame merge into it; frame ranges and names that cannot work are refused.
#[test]
fn frames_render_each_frame_at_its_time_to_its_own_file() {
    let dir = folder("frames");
    let scene = dir.join("orbit.toml");
    std::fs::write(&scene, ANIMATED).unwrap();
    let sc = s(&scene);
    let pattern = dir.join("f-###.png");
    let text = ok(&[
        "render",
        sc,
        "--backend",
        "cpu",
        "--frames",
        "2..5",
        "--fps",
        "4",
        "--out",
        s(&pattern),
    ]);
    assert!(
        text.contains("frame at 0.5 s:") && text.contains("frame at 1 s:"),
        "{text}"
    );
    let frames: Vec<PathBuf> = (2..5).map(|k| dir.join(format!("f-{k:03}.png"))).collect();
    for f in &frames {
        assert!(f.exists(), "{} not written:\n{text}", f.display());
    }
    assert!(!dir.join("f-001.png").exists() && !dir.join("f-005.png").exists());
    // Frame 3 at 4 frames per second is time 0.75 s.
    let at = dir.join("at.png");
    ok(&["render", sc, "--backend", "cpu", "--time", "0.75", "--out", s(&at)]);
    assert_eq!(std::fs::read(&at).unwrap(), std::fs::read(&frames[1]).unwrap());
    assert_ne!(
        std::fs::read(&frames[0]).unwrap(),
        std::fs::read(&frames[1]).unwrap(),
        "the ball did not move between frames"
    );

    // Shards of one frame (a farm's unit of work: frame by sample range).
    let shard_pattern = dir.join("s-####.exr");
    for spec in ["0/2", "1/2"] {
        let shard_pattern = shard_pattern.with_file_name(format!("s{}-####.exr", &spec[..1]));
        ok(&[
            "render",
            sc,
            "--backend",
            "cpu",
            "--frames",
            "3..4",
            "--fps",
            "4",
            "--shard",
            spec,
            "--out",
            s(&shard_pattern),
        ]);
    }
    let (merged, at_exr) = (dir.join("merged.exr"), dir.join("at.exr"));
    ok(&[
        "merge",
        s(&dir.join("s0-0003.exr")),
        s(&dir.join("s1-0003.exr")),
        "--out",
        s(&merged),
    ]);
    ok(&["render", sc, "--backend", "cpu", "--time", "0.75", "--out", s(&at_exr)]);
    let d = max_relative_difference(&linear(&at_exr), &linear(&merged));
    assert!(d < 1e-5, "a frame's merged shards differ from its render by {d}");
    // Shards of different frames are different renders.
    ok(&[
        "render",
        sc,
        "--backend",
        "cpu",
        "--frames",
        "4..5",
        "--fps",
        "4",
        "--shard",
        "1/2",
        "--out",
        s(&shard_pattern),
    ]);
    let text = fails(&[
        "merge",
        s(&dir.join("s0-0003.exr")),
        s(&dir.join("s-0004.exr")),
        "--out",
        s(&merged),
    ]);
    assert!(text.contains("hashes"), "{text}");

    for (extra, says) in [
        (&["--frames", "5..5"][..], "A < B"),
        (&["--frames", "x"][..], "frames are A..B"),
        (
            &["--frames", "0..2", "--out", "plain.png"][..],
            "needs # where the frame number goes",
        ),
        (
            &["--frames", "0..2", "--fps", "0"][..],
            "--fps must be a positive number",
        ),
    ] {
        let mut args = vec!["render", sc, "--backend", "cpu"];
        args.extend(extra);
        let text = fails(&args);
        assert!(text.contains(says), "{extra:?}: {text}");
    }
}
