//! Benchmarks, one module each, and what they share (the median, report files, names): the
//! BVH build (`build`), the thesis's tables (`table2`), real-time frames (`realtime`), trace
//! throughput per BVH layout (`trace`), specialised kernels (`features`), what accuracy costs
//! in time (`accuracy`, and for the real-time denoiser `denoise`), one render on several
//! devices (`devices`), instancing's two levels (`levels`), our tracer against the driver's
//! acceleration structures (`peer`), and README's performance section
//! made from their results (`readme`). Results go to `bench/results`, each file naming the GPU
//! and driver; `plot` draws their charts.
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

pub mod accuracy;
pub mod build;
pub mod denoise;
pub mod devices;
pub mod features;
pub mod levels;
pub mod peer;
pub mod plot;
pub mod readme;
pub mod realtime;
pub mod table2;
pub mod trace;

/// The `q` quantile (0..=1, nearest rank) of ascending `sorted` values; NaN when empty.
/// Runs `f` at least 10 times and for at least half a second after the first (which may
/// create pipelines): the GPU's clocks up. They drop within a fraction of a second of idling
/// (a pipeline's creation is enough), and short submissions each followed by a wait do not
/// raise them again: `bench features` measured specialised kernels 1.5-4x slow without this.
pub fn warm(mut f: impl FnMut() -> Result<()>) -> Result<()> {
    f()?;
    let start = std::time::Instant::now();
    let mut runs = 0;
    while runs < 10 || start.elapsed() < std::time::Duration::from_millis(500) {
        f()?;
        runs += 1;
    }
    Ok(())
}

pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Writes a report as `dir/stem.md` (`markdown`) and `dir/stem.json` (`value`); returns the
/// Markdown file's path.
pub fn write_files(dir: &Path, stem: &str, markdown: &str, value: &impl serde::Serialize) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let md = dir.join(format!("{stem}.md"));
    std::fs::write(&md, markdown).with_context(|| format!("writing {}", md.display()))?;
    let json = dir.join(format!("{stem}.json"));
    std::fs::write(&json, serde_json::to_string_pretty(value)?)
        .with_context(|| format!("writing {}", json.display()))?;
    Ok(md)
}

/// File-name-safe form of a device name.
pub fn slug(s: &str) -> String {
    let mut out: String = s
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect();
    while out.contains("--") {
        out = out.replace("--", "-");
    }
    out.trim_matches('-').to_string()
}
