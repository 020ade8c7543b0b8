//! Helpers of the stability tests: primitives with the BVH the CPU executor builds; closed
//! meshes with shared vertices (from `raytrace::inputs::hard_cases`); random numbers from the kernels' own streams; units in the
//! last place; and a chi-square critical value.
#![allow(dead_code)]

pub mod rays;

use raytrace::bvh::{BuildOptions, MortonBits};
#[allow(unused_imports)]
pub use raytrace::inputs::hard_cases::{cube, icosphere, octahedron, rays_at_vertices_and_edges, Mesh, OFFSETS};
use shared::glam::Vec3;
use shared::rng::Rng;
use shared::traverse::Scene;
use shared::types::{Frame, Hit, Node, Ray, Sphere, Triangle, FEATURES_ALL, FLAG_BVH, INVALID};
use shared::wide::WideNode;

/// Primitives and the 30-bit LBVH over them, collapsed into the wide BVH where the suite
/// runs through it (`crate::WIDE`: the stability suite runs twice, `stability` through the
/// binary BVH and `stability_wide` through the wide one).
pub struct World {
    pub tris: Vec<Triangle>,
    pub spheres: Vec<Sphere>,
    pub nodes: Vec<Node>,
    pub wide: Vec<WideNode>,
    pub order: Vec<u32>,
}

impl World {
    /// The primitives with the BVH of the CPU executor (the kernels the GPU runs), which
    /// must pass the validator.
    pub fn new(tris: Vec<Triangle>, spheres: Vec<Sphere>) -> World {
        let r = raytrace::cpu::build(&tris, &spheres, World::build()).0;
        let n_tris = tris.len() as u32;
        let finite = (0..n_tris + spheres.len() as u32).all(|i| {
            let (lo, hi) = shared::types::prim_box(i, n_tris, &tris, &spheres);
            lo.is_finite() && hi.is_finite()
        });
        // Broken primitives (non-finite vertices) have no box to contain.
        if crate::WIDE && finite {
            if let Err(e) = raytrace::bvh::validate_wide(&r.wide, &r.sorted_prims, &tris, &spheres) {
                panic!("the CPU's wide BVH is invalid: {e}");
            }
        }
        World {
            tris,
            spheres,
            nodes: r.traced_nodes(),
            wide: r.wide,
            order: r.sorted_prims,
        }
    }

    /// How the suite's BVHs are built.
    pub fn build() -> BuildOptions {
        if crate::WIDE {
            BuildOptions::wide(MortonBits::B30)
        } else {
            BuildOptions::lbvh(MortonBits::B30)
        }
    }

    /// The scene traversed through the BVH (the wide one where the suite runs through it).
    pub fn scene(&self) -> Scene<'_> {
        Scene {
            tris: bytemuck::cast_slice(&self.tris),
            spheres: &self.spheres,
            nodes: bytemuck::cast_slice(&self.nodes),
            wide: bytemuck::cast_slice(&self.wide),
            order: &self.order,
            n_tris: self.tris.len() as u32,
            n_prims: (self.tris.len() + self.spheres.len()) as u32,
            top: 0,
            instances: &[],
            n_instances: 0,
            coverage: shared::alpha::Coverage::NONE,
            features: raytrace::render::tracer_features(
                &Frame {
                    features: FEATURES_ALL,
                    ..Default::default()
                },
                World::build(),
            ),
        }
    }
}

/// Uniform numbers from the kernels' own stream (fixed seed per test).
pub struct Random(Rng);

impl Random {
    pub fn new(seed: u32) -> Random {
        Random(Rng::new(seed, 0, 0x5eed))
    }
    pub fn f32(&mut self) -> f32 {
        self.0.next_f32()
    }
    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.0.next_f32()
    }
    /// Uniform in `[0, 1)` with 53 random bits, for f64 references.
    pub fn f64(&mut self) -> f64 {
        let hi = (self.0.next_u32() >> 5) as u64;
        let lo = (self.0.next_u32() >> 6) as u64;
        ((hi << 26) | lo) as f64 / (1u64 << 53) as f64
    }
    pub fn rng(&mut self) -> &mut Rng {
        &mut self.0
    }
    /// Uniform unit vector.
    pub fn unit(&mut self) -> Vec3 {
        let (u1, u2) = (self.f32(), self.f32());
        shared::sampling::uniform_sphere(u1, u2)
    }
}

/// Spacing of `f32` values at `x` (the ulp of `x` rounded to `f32`).
pub fn ulp_f32(x: f64) -> f64 {
    let a = (x as f32).abs();
    if a == 0.0 {
        return f32::from_bits(1) as f64;
    }
    let next = f32::from_bits(a.to_bits() + 1);
    (next - a) as f64
}

/// Distance of `x` from the reference `reference` in units of `f32` spacing at `reference`.
pub fn ulps(x: f32, reference: f64) -> f64 {
    (x as f64 - reference).abs() / ulp_f32(reference)
}

/// Upper standard normal quantile: `z` with `P(Z > z) = p`, for `p <= 0.5` (Abramowitz &
/// Stegun 26.2.23, absolute error below 4.5e-4).
pub fn normal_quantile_upper(p: f64) -> f64 {
    let t = (-2.0 * p.ln()).sqrt();
    t - (2.515517 + 0.802853 * t + 0.010328 * t * t) / (1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t * t * t)
}

/// Chi-square value exceeded with probability `p` at `dof` degrees of freedom
/// (Wilson & Hilferty 1931: the cube root of chi-square / dof is nearly normal).
pub fn chi_square_critical(dof: f64, p: f64) -> f64 {
    let z = normal_quantile_upper(p);
    let h = 2.0 / (9.0 * dof);
    dof * (1.0 - h + z * h.sqrt()).powi(3)
}

/// Pearson's chi-square of observed `counts` against equal expected counts.
pub fn chi_square_uniform(counts: &[u64]) -> f64 {
    let n: u64 = counts.iter().sum();
    let e = n as f64 / counts.len() as f64;
    counts.iter().map(|&c| (c as f64 - e).powi(2) / e).sum()
}

/// Runs `f` on a thread and fails if it has not returned after `secs` seconds: a guard that
/// turns a hang into a failure, not a timing measurement.
pub fn returns_within<T: Send + 'static>(secs: u64, what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(std::time::Duration::from_secs(secs))
        .unwrap_or_else(|e| panic!("{what}: did not return ({e})"))
}

/// Primitives on the GPU, placed by the transform stage (one identity-transformed mesh
/// object, one object per sphere translated to its centre: both exact) with the BVH the
/// GPU builds, queried through the `cast_rays` kernel.
pub struct GpuWorld {
    pub gpu: std::sync::Arc<raytrace::gpu::Gpu>,
    renderer: raytrace::gpu::GpuRenderer,
    frame: shared::types::Frame,
}

impl GpuWorld {
    /// The device with validation on, or `None` (after a skip line) where there is none.
    pub fn open(test: &str) -> Option<GpuWorld> {
        let gpu = integration_tests::gpu(test)?;
        let kernels = std::sync::Arc::new(raytrace::gpu::Kernels::new(&gpu).expect("kernels"));
        let renderer = raytrace::gpu::GpuRenderer::new(&gpu, &kernels).expect("renderer");
        Some(GpuWorld {
            gpu,
            renderer,
            frame: Default::default(),
        })
    }

    /// [`GpuWorld::open`] with the queries traced by the driver's acceleration structures
    /// (`--accel driver`), or `None` (after a skip line) where the device has none.
    #[allow(dead_code)]
    pub fn open_driver(test: &str) -> Option<GpuWorld> {
        let gpu = integration_tests::ray_tracing_gpu(test)?;
        let kernels = std::sync::Arc::new(raytrace::gpu::Kernels::new(&gpu).expect("kernels"));
        let mut renderer = raytrace::gpu::GpuRenderer::new(&gpu, &kernels).expect("renderer");
        renderer
            .set_accel(raytrace::render::Accel::Driver, Default::default())
            .expect("the driver tracer");
        Some(GpuWorld {
            gpu,
            renderer,
            frame: Default::default(),
        })
    }

    /// Loads the primitives as a scene (`hard_cases::scene_of`) with every feature; its frame.
    fn load_primitives(&mut self, tris: &[Triangle], spheres: &[Sphere]) -> shared::types::Frame {
        let scene = raytrace::inputs::hard_cases::scene_of(tris, spheres);
        let data = scene.gpu_data(0.0);
        let mut frame = scene.frame(&data);
        frame.features = FEATURES_ALL;
        self.renderer.set_build(World::build());
        self.renderer.load(&data, &frame).expect("load");
        frame
    }

    /// Loads `w`'s primitives and builds their BVH on the GPU, which must pass the validator;
    /// queries go through the BVH.
    pub fn load(&mut self, w: &World) {
        let frame = self.load_primitives(&w.tris, &w.spheres);
        let r = &mut self.renderer;
        r.render(0, true).expect("transform and build");
        let (tris, spheres) = r.world().expect("world-space primitives");
        assert!(
            tris == w.tris && spheres == w.spheres,
            "the transform stage moved the primitives"
        );
        if r.accel() == raytrace::render::Accel::Driver {
            // The driver built its own structures: nothing of the project's to check.
            self.frame = frame;
            return;
        }
        let bvh = r.bvh().expect("BVH");
        if let Err(e) = raytrace::bvh::validate(&bvh.nodes, &bvh.parents, &tris, &spheres) {
            panic!("the GPU's BVH is invalid: {e}");
        }
        // The frame's transform stage reduced the build's bounds (`transform_bounds`), the
        // CPU executor's bounds stage its output: the same tree, bit for bit.
        assert_eq!(
            bvh.traced_nodes(),
            w.nodes,
            "the GPU's BVH (built by the renderer's frame) differs from the CPU executor's"
        );
        if crate::WIDE {
            if let Err(e) = raytrace::bvh::validate_wide(&bvh.wide, &bvh.sorted_prims, &tris, &spheres) {
                panic!("the GPU's wide BVH is invalid: {e}");
            }
            assert_eq!(bvh.wide, w.wide, "the GPU's wide BVH differs from the CPU executor's");
        }
        self.frame = frame;
    }

    /// Loads the two levels `l` (built by the CPU executor): the ray casts walk them.
    pub fn load_levels(&mut self, l: &raytrace::bvh::Levels) {
        self.load_primitives(&l.tris, &l.spheres);
        let r = &mut self.renderer;
        r.load_levels(l).expect("load the levels");
        self.frame = *r.frame();
    }

    /// Queries through the BVH (`bvh`) or by brute force, with `variants` (`VARIANT_*`).
    pub fn set_mode(&mut self, bvh: bool, variants: u32) {
        let mut f = self.frame;
        f.flags = if bvh { f.flags | FLAG_BVH } else { f.flags & !FLAG_BVH };
        f.features = FEATURES_ALL | variants;
        self.renderer.set_frame(&f).expect("frame");
    }

    /// Closest hits of `(origin, direction, t_max)` rays.
    pub fn closest(&mut self, rays: &[(Vec3, Vec3, f32)]) -> Vec<Hit> {
        self.renderer.cast(&to_rays(rays)).expect("cast")
    }

    /// Whether anything lies along each ray.
    pub fn any(&mut self, rays: &[(Vec3, Vec3, f32)]) -> Vec<bool> {
        let hits = self.renderer.cast_any(&to_rays(rays)).expect("cast");
        hits.iter().map(|h| h.prim != INVALID).collect()
    }

    /// For each `(primary, direction)`: the primary ray's closest hit and that of a ray
    /// leaving its hit point along `direction`, origin offset on the GPU.
    pub fn spawn(&mut self, pairs: &[((Vec3, Vec3), Vec3)]) -> Vec<(Hit, Hit)> {
        let rays: Vec<(Vec3, Vec3, f32)> = pairs
            .iter()
            .flat_map(|&((o, d), d2)| [(o, d, f32::INFINITY), (Vec3::ZERO, d2, f32::INFINITY)])
            .collect();
        let hits = self.renderer.cast_spawn(&to_rays(&rays)).expect("cast");
        hits.chunks(2).map(|h| (h[0], h[1])).collect()
    }

    pub fn assert_no_validation_errors(&self) {
        integration_tests::assert_no_validation_errors(&self.gpu);
    }
}

fn to_rays(rays: &[(Vec3, Vec3, f32)]) -> Vec<Ray> {
    rays.iter()
        .map(|&(o, d, t_max)| Ray {
            origin: [o.x, o.y, o.z, 0.0],
            dir: [d.x, d.y, d.z, t_max],
        })
        .collect()
}
