//! `raytrace bench build`: GPU time of every build stage (timestamp queries, warm-up
//! discarded, median of many runs), primitives per second, BVH bytes per primitive, and the
//! CPU executor's time on the same input; the GPU result is checked against the CPU's after
//! timing. Writes Markdown and JSON.
use crate::bvh::{validate, validate_wide, BuildOptions, MortonBits, STAGES};

/// Reported columns: the stages, and the wide collapse's write pass (0 for binary builds;
/// the fit of a wide build decides the collapse, in the `refit` stage).
const COLUMNS: [&str; 6] = [STAGES[0], STAGES[1], STAGES[2], STAGES[3], STAGES[4], "wide"];
use super::accuracy::{sah_cost, sah_cost_wide};
use super::{percentile, write_files};
use crate::cpu;
use crate::gpu::{Gpu, GpuLbvh, Kernels};
use crate::inputs::{assets_dir, generate, load_obj, Distribution};
use anyhow::{bail, Result};
use serde::Serialize;
use shared::types::{Sphere, Triangle};
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One benchmark input.
pub struct Input {
    pub name: String,
    pub tris: Vec<Triangle>,
    pub spheres: Vec<Sphere>,
}

#[derive(Serialize)]
pub struct BuildRow {
    pub input: String,
    pub primitives: usize,
    pub bits: MortonBits,
    /// Whether the refit restructured treelets (its time is in the `refit` column).
    pub treelets: bool,
    /// Whether the tree was collapsed into the wide BVH (its time is the `wide` column).
    pub wide: bool,
    /// Whether H-PLOC built the tree and its boxes (its time is the `tree` column).
    pub ploc: bool,
    /// Surface-area cost of the tree traced (`accuracy::sah_cost`, `sah_cost_wide`).
    pub sah: f64,
    pub runs: usize,
    /// Median GPU microseconds per column of `COLUMNS`.
    pub stage_us: Vec<(String, f64)>,
    /// Median total of the builds timed without stage timestamps.
    pub total_us: f64,
    pub total_p10_us: f64,
    pub total_p90_us: f64,
    /// Median of builds run back to back in one submission (as the renderer's frames run).
    pub streamed_us: f64,
    /// Median GPU time of a refit of the built tree (`GpuLbvh::refit`: its internal boxes
    /// emptied and fitted again, the other stages skipped), as `total` is timed; none where
    /// the tree cannot be refit (treelets, wide).
    pub refit_us: Option<f64>,
    pub mprims_per_s: f64,
    pub bvh_bytes_per_prim: f64,
    pub scratch_bytes_per_prim: f64,
    pub cpu_ms: f64,
    pub matches_cpu: bool,
    pub depth: u32,
}

#[derive(Serialize)]
pub struct BuildReport {
    pub date: String,
    pub device: String,
    pub command: String,
    pub rows: Vec<BuildRow>,
}

/// Nanoseconds of the intervals labelled `name` or `name.<part>`.
fn column_ns(t: &[(&str, f64)], name: &str) -> f64 {
    t.iter()
        .filter(|(l, _)| *l == name || l.strip_prefix(name).is_some_and(|r| r.starts_with('.')))
        .map(|(_, ns)| ns)
        .sum()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    percentile(&v, 0.5)
}

/// The standard inputs: 37 primitives, Suzanne, the bunny, and `sizes` random triangles.
pub fn standard_inputs(sizes: &[usize]) -> Result<Vec<Input>> {
    let mut v = Vec::new();
    let (t, s) = generate(37, Distribution::Random, true, 37);
    v.push(Input {
        name: "37 mixed".into(),
        tris: t,
        spheres: s,
    });
    for mesh in ["suzanne", "bunny"] {
        let path = assets_dir().join(format!("{mesh}.obj"));
        v.push(Input {
            name: mesh.into(),
            tris: load_obj(&path)?,
            spheres: Vec::new(),
        });
    }
    for &n in sizes {
        let (t, s) = generate(n, Distribution::Random, false, n as u64);
        v.push(Input {
            name: format!("{}M random", n as f64 / 1e6),
            tris: t,
            spheres: s,
        });
    }
    Ok(v)
}

/// Times the build of every input; fails if any GPU result differs from the CPU's.
pub fn bench_build(
    gpu: &Arc<Gpu>,
    inputs: &[Input],
    opts: BuildOptions,
    runs: usize,
    warmup: usize,
) -> Result<Vec<BuildRow>> {
    let kernels = Arc::new(Kernels::new(gpu)?);
    let mut lbvh = GpuLbvh::new(gpu, &kernels)?;
    let mut rows = Vec::new();
    for input in inputs {
        let n = input.tris.len() + input.spheres.len();
        eprintln!("bench build: {} ({n} primitives, {opts:?})", input.name);
        lbvh.upload(&input.tris, &input.spheres)?;
        // Warm up for at least `warmup` builds and half a second, in batches that keep the GPU
        // busy ~5 ms each. Its clocks drop within a fraction of a second of idling (the CPU
        // executor's runs, pipeline creation), and a stream of short builds each followed by a
        // CPU wait does not raise them again: small inputs then measured 2.5-4x slow.
        let once = lbvh.build_total(opts)?;
        let batch = ((5e6 / once.max(1.0)) as usize).clamp(1, 256);
        let warm_start = std::time::Instant::now();
        let mut warmed = 0;
        while warmed < warmup || warm_start.elapsed() < std::time::Duration::from_millis(500) {
            lbvh.build_repeated(opts, batch)?;
            warmed += batch;
        }
        // Stage times come from builds with a timestamp after every stage; the totals from
        // builds without (as the renderer runs them): each timestamp costs about a microsecond.
        let mut per_column: Vec<Vec<f64>> = vec![Vec::new(); COLUMNS.len()];
        let mut totals = Vec::new();
        for _ in 0..runs {
            let t = lbvh.build(opts, false)?;
            for (c, name) in COLUMNS.iter().enumerate() {
                per_column[c].push(column_ns(&t, name) / 1e3);
            }
            totals.push(lbvh.build_total(opts)? / 1e3);
        }
        totals.sort_by(f64::total_cmp);
        let total_us = percentile(&totals, 0.5);
        let mut streamed = Vec::new();
        while streamed.len() < runs {
            let batch = (runs - streamed.len()).min(GpuLbvh::STREAM_MAX);
            streamed.extend(lbvh.build_streamed(opts, batch)?.iter().map(|ns| ns / 1e3));
        }

        // Check after timing: the GPU's output must equal the CPU executor's, and be valid.
        lbvh.build(opts, true)?;
        let gpu_result = lbvh.result(opts)?;
        // A refit over the same primitives must leave the tree as built.
        let refit_us = if opts.wide || opts.restructures() {
            None
        } else {
            let mut times = Vec::new();
            for _ in 0..runs {
                times.push(lbvh.refit(opts)? / 1e3);
            }
            if lbvh.result(opts)?.nodes != gpu_result.nodes {
                bail!(
                    "refitting the BVH of {} over the same primitives changed it",
                    input.name
                );
            }
            Some(median(times))
        };
        let cpu_runs = if n >= 1_000_000 { 1 } else { 3 };
        let mut cpu_times = Vec::new();
        let mut cpu_result = None;
        for _ in 0..cpu_runs {
            let t = std::time::Instant::now();
            let (r, _) = cpu::build(&input.tris, &input.spheres, opts);
            cpu_times.push(t.elapsed().as_secs_f64() * 1e3);
            cpu_result = Some(r);
        }
        // A device whose binding cannot hold the pairs builds without them
        // (`GpuLbvh::has_pairs`): everything else is compared.
        if let Some(c) = cpu_result.as_mut().filter(|_| gpu_result.pairs.is_empty()) {
            c.pairs.clear();
        }
        let matches_cpu = cpu_result.as_ref() == Some(&gpu_result);
        let mut stats = validate(&gpu_result.nodes, &gpu_result.parents, &input.tris, &input.spheres)
            .map_err(|e| anyhow::anyhow!("GPU BVH of {} is invalid:\n{e}", input.name))?;
        let (sah, bvh_bytes) = if opts.wide {
            let w = validate_wide(&gpu_result.wide, &gpu_result.sorted_prims, &input.tris, &input.spheres)
                .map_err(|e| anyhow::anyhow!("GPU wide BVH of {} is invalid:\n{e}", input.name))?;
            stats.depth = w.depth;
            (
                sah_cost_wide(&gpu_result.wide),
                w.nodes * size_of::<shared::wide::WideNode>(),
            )
        } else {
            // The tree, and the padding and pairs where the build wrote them.
            let pairs = gpu_result.pairs.len() + usize::from(!gpu_result.pairs.is_empty());
            let traced = gpu_result.nodes.len() + pairs;
            (sah_cost(&gpu_result.nodes), traced * size_of::<shared::types::Node>())
        };
        if !matches_cpu {
            bail!("GPU build of {} differs from the CPU executor's", input.name);
        }
        let (_, scratch) = lbvh.memory();
        rows.push(BuildRow {
            input: input.name.clone(),
            primitives: n,
            bits: opts.bits,
            treelets: opts.restructures(),
            wide: opts.wide,
            ploc: opts.builds_ploc(),
            sah,
            runs,
            stage_us: COLUMNS
                .iter()
                .zip(per_column)
                .map(|(s, v)| (s.to_string(), median(v)))
                .collect(),
            total_us,
            total_p10_us: percentile(&totals, 0.1),
            total_p90_us: percentile(&totals, 0.9),
            streamed_us: median(streamed),
            refit_us,
            mprims_per_s: n as f64 / total_us,
            bvh_bytes_per_prim: bvh_bytes as f64 / n.max(1) as f64,
            scratch_bytes_per_prim: scratch as f64 / n.max(1) as f64,
            cpu_ms: median(cpu_times),
            matches_cpu,
            depth: stats.depth,
        });
    }
    Ok(rows)
}

/// Markdown table of a report.
pub fn markdown(r: &BuildReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# BVH build benchmark\n\n- date: {}\n- device: {}\n- command: `{}`\n",
        r.date, r.device, r.command
    );
    let _ = writeln!(
        s,
        "Median GPU time over the runs after warm-up (timestamp queries), microseconds. \
         Stage columns come from builds with a timestamp after every stage; `total` is the \
         median over builds without them (p10-p90 beside it), as the renderer runs the build \
         (each timestamp costs about a microsecond), each its own submission with a CPU wait \
         after it; `streamed` is the median over builds run back to back in one submission, \
         as the renderer's frames run them (no idle GPU between builds); `refit`: a refit of the \
         built tree (internal boxes emptied, the fit run again; bounds, codes, sort and tree \
         kept; an H-PLOC tree's by the counter refit), timed as `total` (none for treelets or wide \
         trees, which cannot be refit); an H-PLOC build's tree and boxes are one kernel, timed in \
         `tree`; a binary build's `refit` stage includes its pairs (each internal node's \
         children as one 64-byte pair, as the binary walk reads them: written by the fit, and \
         those of the nodes above its blocks by a pass after it; after treelets or H-PLOC by a \
         pass over every node), a wide build's \
         the collapse's decisions (its fit decides which binary nodes root wide nodes; `wide` \
         is the pass writing them). BVH bytes count \
         the nodes traced (a binary build: the tree and its pairs; a wide build: the wide \
         nodes it wrote, at their binary roots' indices in a buffer with a slot per binary \
         internal node, counted under scratch with the binary tree); scratch is everything else the builder holds (inputs included). SAH: \
         surface-area cost of the tree traced (node areas, and leaf areas once per primitive, \
         over the root's).\n"
    );
    let _ = write!(s, "| input | prims | bits | runs |");
    for st in COLUMNS {
        let _ = write!(s, " {st} |");
    }
    let _ = writeln!(
        s,
        " total (p10-p90) | streamed | refit | Mprims/s | BVH B/prim | scratch B/prim | SAH | depth | CPU executor ms | equals CPU |"
    );
    let _ = writeln!(s, "|{}", "---|".repeat(4 + COLUMNS.len() + 10));
    for row in &r.rows {
        let _ = write!(
            s,
            "| {} | {} | {:?}{}{} | {} |",
            row.input,
            row.primitives,
            row.bits,
            if row.treelets { " + treelets" } else { "" },
            if row.wide {
                " wide"
            } else if row.ploc {
                " H-PLOC"
            } else {
                ""
            },
            row.runs
        );
        for (_, us) in &row.stage_us {
            let _ = write!(s, " {us:.1} |");
        }
        let _ = writeln!(
            s,
            " {:.1} ({:.1}-{:.1}) | {:.1} | {} | {:.0} | {:.1} | {:.1} | {:.1} | {} | {:.1} | {} |",
            row.total_us,
            row.total_p10_us,
            row.total_p90_us,
            row.streamed_us,
            row.refit_us.map_or("-".to_string(), |us| format!("{us:.1}")),
            row.mprims_per_s,
            row.bvh_bytes_per_prim,
            row.scratch_bytes_per_prim,
            row.sah,
            row.depth,
            row.cpu_ms,
            if row.matches_cpu { "yes" } else { "NO" }
        );
    }
    s
}

/// Writes `<stem>.md` and `<stem>.json` into `dir`; returns the Markdown path.
pub fn write_report(r: &BuildReport, dir: &Path, stem: &str) -> Result<PathBuf> {
    write_files(dir, stem, &markdown(r), r)
}
