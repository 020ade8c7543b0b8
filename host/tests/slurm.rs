//! The Slurm job-array scripts (`scripts/slurm`, docs/cluster.md) under a real single-node
//! Slurm cluster started for the test (`scripts/slurm/local-cluster.sh`): a 4-task array renders
//! the shards of a frame on the CPU executor, a job that depends on it merges them, and the
//! merged image equals a single render's. Needs root and Debian's slurmctld, slurmd,
//! slurm-client and munge (CI installs them and runs as root); elsewhere it prints SKIPPED and
//! why.
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_raytrace");

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Why the test cannot run here, if it cannot.
fn unavailable() -> Option<String> {
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0");
    if !root {
        return Some("starting Slurm's daemons needs root".into());
    }
    let missing: Vec<&str> = [
        "/usr/sbin/slurmctld",
        "/usr/sbin/slurmd",
        "/usr/sbin/munged",
        "/usr/bin/sbatch",
    ]
    .into_iter()
    .filter(|p| !Path::new(p).exists())
    .collect();
    (!missing.is_empty()).then(|| {
        format!(
            "{} missing (apt-get install slurmctld slurmd slurm-client munge)",
            missing.join(", ")
        )
    })
}

/// The cluster, stopped when dropped.
struct Cluster {
    dir: PathBuf,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        // A port of this process's own, so that runs side by side do not meet.
        let port = 20000 + std::process::id() % 20000;
        let o = Command::new("bash")
            .arg(repo().join("scripts/slurm/local-cluster.sh"))
            .args(["start", dir.to_str().unwrap(), &port.to_string()])
            .output()
            .expect("running local-cluster.sh");
        let cluster = Cluster { dir: dir.to_path_buf() };
        assert!(
            o.status.success(),
            "the local Slurm cluster did not start:\n{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        cluster
    }

    /// `sbatch ARGS` against this cluster, with `raytrace` on the jobs' PATH; the job id.
    fn sbatch(&self, args: &[&str]) -> String {
        let bin_dir = Path::new(BIN).parent().unwrap();
        let path = format!("{}:{}", bin_dir.display(), std::env::var("PATH").unwrap_or_default());
        // `timeout`: a job that never runs fails the test instead of hanging it.
        let o = Command::new("timeout")
            .args(["300", "sbatch", "--parsable", "--time=5", "--chdir"])
            .arg(&self.dir)
            .args(args)
            .env("SLURM_CONF", self.dir.join("slurm.conf"))
            .env("PATH", path)
            .output()
            .expect("running sbatch");
        assert!(
            o.status.success(),
            "sbatch {} failed:\n{}{}\n{}",
            args.join(" "),
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr),
            self.logs()
        );
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    }

    fn logs(&self) -> String {
        let mut s = String::new();
        for entry in std::fs::read_dir(&self.dir).into_iter().flatten().flatten() {
            let p = entry.path();
            if p.extension().is_some_and(|e| e == "log") {
                s += &format!(
                    "--- {}\n{}\n",
                    p.display(),
                    std::fs::read_to_string(&p).unwrap_or_default()
                );
            }
        }
        s
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(repo().join("scripts/slurm/local-cluster.sh"))
            .args(["stop", self.dir.to_str().unwrap()])
            .status();
    }
}

fn linear(path: &Path) -> Vec<f32> {
    image::open(path)
        .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
        .into_rgb32f()
        .into_raw()
}

#[test]
fn a_slurm_job_array_renders_shards_that_merge_into_the_single_run() {
    if let Some(why) = unavailable() {
        eprintln!("SKIPPED a_slurm_job_array_renders_shards_that_merge_into_the_single_run: {why}");
        return;
    }
    let dir = std::env::temp_dir().join(format!("raytrace-slurm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cluster = Cluster::start(&dir);
    let scripts = repo().join("scripts/slurm");
    let (render, merge) = (scripts.join("render-shards.sbatch"), scripts.join("merge.sbatch"));
    let (shards, merged, single) = (dir.join("shards"), dir.join("merged.exr"), dir.join("single.exr"));
    let settings = ["--size", "32x24", "--spp", "8", "--backend", "cpu"];

    let mut args = vec![
        "--array=0-3",
        render.to_str().unwrap(),
        "cornell",
        "4",
        shards.to_str().unwrap(),
    ];
    args.extend(settings);
    let array = cluster.sbatch(&args);
    let after = format!("--dependency=afterok:{array}");
    cluster.sbatch(&[
        "--wait",
        &after,
        merge.to_str().unwrap(),
        shards.to_str().unwrap(),
        merged.to_str().unwrap(),
    ]);
    assert!(merged.exists(), "the merge job wrote nothing:\n{}", cluster.logs());
    for i in 0..4 {
        assert!(shards.join(format!("shard-{i}.exr")).exists(), "no shard {i}");
    }

    let mut args = vec!["render", "cornell"];
    args.extend(settings);
    args.extend(["--out", single.to_str().unwrap()]);
    let o = Command::new(BIN).args(&args).output().expect("running raytrace");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (linear(&single), linear(&merged));
    assert_eq!(a.len(), b.len());
    let peak = a.iter().fold(0f32, |m, &v| m.max(v));
    let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
    assert!(
        worst <= 1e-5 * peak,
        "the array job's merged image differs from a single render by {worst} (peak {peak})"
    );
    drop(cluster);
    let _ = std::fs::remove_dir_all(&dir);
}
