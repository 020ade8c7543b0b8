//! Build inputs: generated primitive sets for tests and benchmarks (fixed seeds), and OBJ
//! meshes loaded with tobj (from the assets folder, else from the copies built into the
//! binary: `builtin_assets`). Bad input gets an error naming the file and the problem.
//! `hard_cases` holds the inputs that break naive ray tracers.
pub mod hard_cases;

mod builtin_assets;

use anyhow::{bail, Context, Result};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use shared::types::{Sphere, Triangle};
use std::path::Path;

/// Shapes of generated input that stress the builder.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Distribution {
    /// Small triangles and spheres uniform in a cube.
    Random,
    /// Every primitive identical: all Morton codes equal.
    AllEqual,
    /// Random, plus one primitive 1e6 units away: 30-bit codes collapse.
    FarOutlier,
    /// Centroids on one line.
    Collinear,
    /// Only 7 distinct primitives, repeated.
    DuplicateHeavy,
}

impl Distribution {
    pub const ALL: [Distribution; 5] = [
        Distribution::Random,
        Distribution::AllEqual,
        Distribution::FarOutlier,
        Distribution::Collinear,
        Distribution::DuplicateHeavy,
    ];
}

fn tri(c: [f32; 3], size: f32, rng: &mut Pcg64) -> Triangle {
    let mut v = || {
        let mut p = [0.0; 4];
        for k in 0..3 {
            p[k] = c[k] + size * rng.random_range(-1.0f32..1.0);
        }
        p
    };
    Triangle {
        v0: v(),
        v1: v(),
        v2: v(),
    }
}

/// `n` primitives of `dist`; every fifth one is a sphere when `spheres` is set.
pub fn generate(n: usize, dist: Distribution, spheres: bool, seed: u64) -> (Vec<Triangle>, Vec<Sphere>) {
    let mut rng = Pcg64::seed_from_u64(seed);
    let size = 1.0 / (n.max(1) as f32).cbrt();
    let mut ts = Vec::with_capacity(n);
    let mut ss = Vec::new();
    let fixed: Vec<[f32; 3]> = (0..7).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
    for i in 0..n {
        let c = match dist {
            Distribution::Random => [rng.random(), rng.random(), rng.random()],
            Distribution::AllEqual => [0.5, 0.5, 0.5],
            Distribution::FarOutlier if i == n / 2 => [1e6, -1e6, 1e6],
            Distribution::FarOutlier => [rng.random(), rng.random(), rng.random()],
            Distribution::Collinear => {
                let t: f32 = rng.random();
                [t, 2.0 * t, -t]
            }
            Distribution::DuplicateHeavy => fixed[rng.random_range(0..fixed.len())],
        };
        if spheres && i % 5 == 4 {
            ss.push(Sphere {
                center_radius: [c[0], c[1], c[2], size * 0.5],
            });
        } else if matches!(dist, Distribution::AllEqual | Distribution::DuplicateHeavy) {
            // Identical primitives for identical centres.
            let mut same = Pcg64::seed_from_u64(c[0].to_bits() as u64);
            ts.push(tri(c, size, &mut same));
        } else {
            ts.push(tri(c, size, &mut rng));
        }
    }
    (ts, ss)
}

/// Loads an OBJ mesh (faces triangulated) as triangles; rejects empty meshes and NaN or
/// infinite vertices with an error naming the file, object and vertex. A file of the assets
/// folder ([`assets_dir`]) that is missing there is read from the binary's built-in copy
/// where it has one (`builtin_assets`).
pub fn load_obj(path: &Path) -> Result<Vec<Triangle>> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let loaded = match builtin_assets::instead_of(path, &assets_dir()) {
        Some(mut bytes) => tobj::load_obj_buf(&mut bytes, &opts, |_| Err(tobj::LoadError::OpenFileFailed)),
        None => tobj::load_obj(path, &opts),
    };
    let (models, _) = loaded.with_context(|| format!("reading OBJ file {}", path.display()))?;
    let mut tris = Vec::new();
    for m in &models {
        let pos = &m.mesh.positions;
        if let Some(bad) = pos.iter().position(|x| !x.is_finite()) {
            bail!(
                "{}: object {:?}: vertex {} has a non-finite coordinate ({})",
                path.display(),
                m.name,
                bad / 3 + 1,
                pos[bad]
            );
        }
        let v = |i: u32| -> Result<[f32; 4]> {
            let i = i as usize * 3;
            let p = pos.get(i..i + 3).with_context(|| {
                format!(
                    "{}: object {:?}: face index {} out of range",
                    path.display(),
                    m.name,
                    i / 3
                )
            })?;
            Ok([p[0], p[1], p[2], 0.0])
        };
        for f in m.mesh.indices.as_chunks::<3>().0 {
            tris.push(Triangle {
                v0: v(f[0])?,
                v1: v(f[1])?,
                v2: v(f[2])?,
            });
        }
    }
    if tris.is_empty() {
        bail!("{}: the mesh has no triangles", path.display());
    }
    Ok(tris)
}

/// The project's assets folder (meshes and their attribution): `RAYTRACE_ASSETS`, else
/// `./assets`, else the source tree's. Where the folder lacks a mesh the built-in scenes
/// need, [`load_obj`] reads the binary's copy.
pub fn assets_dir() -> std::path::PathBuf {
    if let Some(dir) = std::env::var_os("RAYTRACE_ASSETS") {
        return dir.into();
    }
    let here = Path::new("assets");
    if here.join("bunny.obj").exists() {
        return here.to_path_buf();
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets")
}
