//! The path tracer (Kajiya's rendering equation by Monte Carlo, as the thesis's `rayColor`):
//! camera rays jittered per sample through a thin lens, closest hits through the BVH or by
//! brute force, material scattering, Russian roulette after three bounces, and next-event
//! estimation toward emissive triangles and spheres weighted against BSDF sampling by
//! multiple importance sampling (Veach 1997, power heuristic), and toward punctual lights.
//! One invocation per pixel adds its samples' radiance into the accumulation image (on the
//! GPU, a scene in two levels with next-event estimation in two passes: [`queue_pixel`] traces
//! a sample and queues its shadow rays, [`resolve_pixel`] casts them and adds the sample).
use crate::denoise::{self, Guide};
use crate::display;
use crate::envmap::{Env, EnvEntry};
use crate::instance::Placed;
use crate::intersect::{self, offset_origin};
use crate::material;
use crate::math::{finite3, max3};
use crate::rng::Rng;
use crate::sampling;
use crate::shading::{self, facing};
use crate::sync;
use crate::texture::TextureInfo;
use crate::traverse::{self, Scene};
use crate::types::{
    xyz, Camera, Frame, Hit, Material, MaterialKind, Object, PunctualLight, Ray, RenderPush, VertexAttrs, CAST_ANY,
    CAST_OBJECT, CAST_SPAWN, DISPLAY_IN_TRACE, FEATURE_ENVMAP, FEATURE_GUIDES, FEATURE_INSTANCES, FEATURE_NEE,
    FEATURE_PUNCTUAL, FEATURE_THIN_LENS, FLAG_BVH, FLAG_MIS, FLAG_NEE, FLAG_RUSSIAN_ROULETTE, INVALID,
    LIGHT_DIRECTIONAL, LIGHT_SPOT, VARIANT_GROUPS,
};
use core::f32::consts::PI;
use spirv_std::glam::Vec3;

/// Bounces before Russian roulette may end a path.
pub const ROULETTE_AFTER: u32 = 3;

/// Everything a path needs to know about the scene.
#[derive(Copy, Clone)]
pub struct World<'a> {
    pub scene: Scene<'a>,
    pub objects: &'a [Object],
    pub prim_object: &'a [u32],
    pub materials: &'a [Material],
    pub lights: &'a [u32],
    pub frame: &'a Frame,
    /// Every mesh's vertex attributes (`Object::attrs` indexes them).
    pub attrs: &'a [VertexAttrs],
    /// Point, spot and directional lights (`frame.n_punctual` of them).
    pub punctual: &'a [PunctualLight],
    /// The environment map's texels and alias table (with [`FEATURE_ENVMAP`]).
    pub env: &'a [EnvEntry],
    /// Every texture's place in `texels`, and the texels (with `FEATURE_TEXTURES`).
    pub textures: &'a [TextureInfo],
    pub texels: &'a [u32],
}

/// A closest hit and where its primitive is ([`Placed::prim`] is `hit.prim`).
#[derive(Copy, Clone)]
pub struct Found {
    pub hit: Hit,
    pub at: Placed,
}

impl Found {
    pub const MISS: Found = Found {
        hit: Hit::MISS,
        at: Placed {
            prim: INVALID,
            object: INVALID,
            model: false,
        },
    };
}

/// How a path's rays find what they hit: the project's own BVH walk ([`Walk`], the
/// methods' defaults), or the driver's acceleration structure through a ray-tracing pipeline
/// (`crate::driver`). The path loop is generic over it, so both tracers shade, sample and
/// count rays with the same code.
pub trait Trace {
    /// [`World::found`]: the closest hit in `(0, t_max)` and where its primitive is.
    fn found(&mut self, w: &World, origin: Vec3, dir: Vec3, t_max: f32) -> Found {
        w.found(origin, dir, t_max)
    }
    /// [`World::any`]: whether anything lies in `(0, t_max)`.
    fn any(&mut self, w: &World, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        w.any(origin, dir, t_max)
    }
    /// [`World::closest`]: the closest hit in `(0, t_max)`.
    fn closest(&mut self, w: &World, origin: Vec3, dir: Vec3, t_max: f32) -> Hit {
        w.closest(origin, dir, t_max)
    }
    /// A shadow ray of next-event estimation in a scene in two levels, bringing `value` if
    /// nothing lies in `(0, t_max)`: what to add now (`value` or zero). [`Queued`] adds
    /// nothing now: it queues the ray for [`resolve_pixel`].
    fn shadow(&mut self, w: &World, origin: Vec3, dir: Vec3, t_max: f32, value: Vec3) -> Vec3 {
        if self.any(w, origin, dir, t_max) {
            Vec3::ZERO
        } else {
            value
        }
    }
}

/// The project's own traversal: the BVH (or brute force without [`FLAG_BVH`]).
pub struct Walk;

impl Trace for Walk {}

/// The path tracer of the shadow queue ([`queue_pixel`]): [`Walk`], but a segment's shadow ray
/// is kept (`pending`) for `queue_pixel` to queue. (No slice of the queue in here: a struct
/// holding a storage buffer's slice made NVIDIA's compiler crash.)
struct Queued {
    pending: bool,
    from: Vec3,
    dir: Vec3,
    t_max: f32,
    value: Vec3,
}

impl Trace for Queued {
    fn shadow(&mut self, _w: &World, origin: Vec3, dir: Vec3, t_max: f32, value: Vec3) -> Vec3 {
        *self = Queued {
            pending: true,
            from: origin,
            dir,
            t_max,
            value,
        };
        Vec3::ZERO
    }
}

impl World<'_> {
    /// The material of the object showing `p`.
    pub fn material(&self, p: Placed) -> Material {
        *sync::at(self.materials, sync::at(self.objects, p.object).material)
    }

    /// Light `k` of `lights` (`k < frame.n_lights`): the emissive primitive, and with
    /// [`FEATURE_INSTANCES`] the object showing it in model space at `lights[n_lights + k]`
    /// ([`INVALID`] for a world-space primitive).
    fn light(&self, k: u32) -> Placed {
        let prim = *sync::at(self.lights, k);
        let object = if self.scene.features & FEATURE_INSTANCES != 0 {
            *sync::at(self.lights, self.frame.n_lights + k)
        } else {
            INVALID
        };
        Placed::shown(self.prim_object, object, prim)
    }

    fn bvh(&self) -> bool {
        self.frame.flags & FLAG_BVH != 0
    }

    pub fn closest(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Hit {
        if self.bvh() {
            traverse::closest(&self.scene, origin, dir, t_max)
        } else {
            traverse::closest_brute(&self.scene, origin, dir, t_max)
        }
    }

    /// [`World::closest`] and where the primitive hit is: through which instance's object
    /// with [`FEATURE_INSTANCES`].
    pub fn found(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Found {
        let (hit, instance) = if self.scene.features & FEATURE_INSTANCES != 0 && self.bvh() {
            traverse::closest_instance(&self.scene, origin, dir, t_max)
        } else {
            (self.closest(origin, dir, t_max), INVALID)
        };
        if hit.prim == INVALID {
            return Found::MISS;
        }
        Found {
            hit,
            at: Placed::hit(self.scene.instances, self.prim_object, instance, hit.prim),
        }
    }

    pub fn any(&self, origin: Vec3, dir: Vec3, t_max: f32) -> bool {
        if self.bvh() {
            traverse::any(&self.scene, origin, dir, t_max)
        } else {
            traverse::any_brute(&self.scene, origin, dir, t_max)
        }
    }

    /// Surface area of primitive `p` in world space.
    pub fn area(&self, p: Placed) -> f32 {
        let s = &self.scene;
        if s.is_triangle(p.prim) {
            0.5 * intersect::triangle_normal(&traverse::triangle_at(s, self.objects, p)).length()
        } else {
            let r = traverse::sphere_at(s, self.objects, p).center_radius[3];
            4.0 * PI * r * r
        }
    }

    /// A uniform point on primitive `prim`: (point, unit normal, the primitive's scale for
    /// [`offset_origin`]).
    fn sample_point(&self, p: Placed, u1: f32, u2: f32) -> (Vec3, Vec3, f32) {
        let s = &self.scene;
        if s.is_triangle(p.prim) {
            let t = &traverse::triangle_at(s, self.objects, p);
            let (b1, b2) = sampling::uniform_triangle(u1, u2);
            (
                intersect::triangle_point(t, b1, b2),
                intersect::triangle_normal(t).normalize(),
                intersect::triangle_scale(t),
            )
        } else {
            let sphere = &traverse::sphere_at(s, self.objects, p);
            let sp = sphere.center_radius;
            let n = sampling::uniform_sphere(u1, u2);
            (xyz(sp) + n * sp[3].abs(), n, intersect::sphere_scale(sphere))
        }
    }

    /// The lights next-event estimation picks from, uniformly: the emissive primitives, then
    /// the punctual lights.
    fn light_count(&self) -> u32 {
        let punctual = if self.scene.features & FEATURE_PUNCTUAL != 0 {
            self.frame.n_punctual
        } else {
            0
        };
        self.frame.n_lights + punctual
    }

    /// Whether the scene has an environment map.
    fn has_env(&self) -> bool {
        let f = self.frame;
        self.scene.features & FEATURE_ENVMAP != 0 && f.env_width > 0 && f.env_height > 0
    }

    /// The environment map (meaningful where [`World::has_env`]). Not an `Option`: rust-gpu
    /// cannot build one around a slice.
    fn env(&self) -> Env<'_> {
        let f = self.frame;
        Env {
            entries: self.env,
            width: f.env_width,
            height: f.env_height,
            rotation: (f.env_rotation[0], f.env_rotation[1]),
            intensity: f.env_intensity,
        }
    }

    /// Probability that next-event estimation samples the environment map rather than the
    /// emissive primitives and punctual lights.
    fn env_prob(&self) -> f32 {
        if self.has_env() {
            self.frame.env_prob
        } else {
            0.0
        }
    }

    /// Solid-angle density with which next-event estimation picks the direction to a point
    /// at distance `dist` on light `prim`, seen at `cos_light` from its normal.
    fn light_pdf(&self, p: Placed, dist: f32, cos_light: f32) -> f32 {
        (1.0 - self.env_prob()) * dist * dist / (cos_light * self.area(p) * self.light_count() as f32)
    }

    /// Cosine between a light's normal and the direction `to_light` from a point toward it;
    /// 0 where the light does not emit that way. Emitters are one-sided: triangles emit on
    /// their front (counter-clockwise) side, spheres outward.
    fn light_cos(normal: Vec3, to_light: Vec3) -> f32 {
        (-normal.dot(to_light)).max(0.0)
    }
}

/// Camera ray through pixel `(x, y)` (row 0 at the top), jittered within the pixel and over
/// the lens: (origin, unit direction).
pub fn camera_ray(c: &Camera, width: u32, height: u32, x: u32, y: u32, features: u32, rng: &mut Rng) -> (Vec3, Vec3) {
    let s = (x as f32 + rng.next_f32()) / width as f32;
    let t = 1.0 - (y as f32 + rng.next_f32()) / height as f32;
    // The lens numbers are drawn either way: a pinhole kernel follows the same streams.
    let (u1, u2) = (rng.next_f32(), rng.next_f32());
    let mut origin = xyz(c.origin);
    if features & FEATURE_THIN_LENS != 0 {
        let (dx, dy) = sampling::uniform_disk(u1, u2);
        let lens = c.u[3];
        origin += xyz(c.u) * (dx * lens) + xyz(c.v) * (dy * lens);
    }
    let target = xyz(c.lower_left) + xyz(c.horizontal) * s + xyz(c.vertical) * t;
    (origin, (target - origin).normalize())
}

/// Origin of a ray leaving the surface point `p` (unit geometric normal `ng`, primitive
/// scale `scale`) along `dir`: offset to the side `dir` goes to.
pub fn leave(p: Vec3, ng: Vec3, scale: f32, dir: Vec3) -> Vec3 {
    offset_origin(p, if dir.dot(ng) > 0.0 { ng } else { -ng }, scale)
}

/// Radiance of rays that leave the scene: the environment map, or the sky gradient.
fn sky(w: &World, d: Vec3) -> Vec3 {
    if w.has_env() {
        return w.env().radiance(d);
    }
    let f = w.frame;
    let a = 0.5 * (d.y + 1.0);
    xyz(f.sky_bottom) * (1.0 - a) + xyz(f.sky_top) * a
}

/// A light sample of next-event estimation: its contribution if nothing blocks the shadow
/// ray `from + t dir`, `t` in `(0, t_max)`.
struct LightSample {
    from: Vec3,
    dir: Vec3,
    t_max: f32,
    value: Vec3,
}

impl LightSample {
    const NONE: LightSample = LightSample {
        from: Vec3::ZERO,
        dir: Vec3::ZERO,
        t_max: 0.0,
        value: Vec3::ZERO,
    };
}

/// Next-event estimation for a path arriving along `d` at point `p` (unit geometric normal
/// `n` and shading normal `sn` on the side the path is on, `scale` its primitive's for
/// [`offset_origin`]) of a non-delta material `m`: the environment map with probability
/// `frame.env_prob`, else one light chosen uniformly among the emissive primitives and
/// punctual lights, for an emitter one point on it uniformly by area. Returns the light
/// sample, its shadow ray not yet cast (see [`bounce`] for where it is).
#[allow(clippy::too_many_arguments)]
fn light_sample(
    w: &World,
    m: &Material,
    d: Vec3,
    p: Vec3,
    n: Vec3,
    sn: Vec3,
    scale: f32,
    mis: bool,
    rng: &mut Rng,
) -> LightSample {
    let count = w.light_count();
    let features = w.scene.features;
    let env_prob = w.env_prob();
    let u = rng.next_f32();
    // The feature tests first: a kernel without a light kind then has no code for it.
    if features & FEATURE_ENVMAP != 0 && (u < env_prob || count == 0) {
        env_light(w, m, d, p, n, sn, scale, mis, rng)
    } else {
        // The rest of the unit interval picks among the local lights.
        let local = (u - env_prob) / (1.0 - env_prob);
        let pick = ((local * count as f32) as u32).min(count - 1);
        if features & FEATURE_PUNCTUAL != 0 && pick >= w.frame.n_lights {
            let l = sync::at(w.punctual, pick - w.frame.n_lights);
            let (wi, mut s) = punctual_light(l, p, n, scale);
            s.value = material::eval(m, d, wi, n, sn, features).0 * s.value * (count as f32 / (1.0 - env_prob));
            s
        } else {
            emitter_light(w, m, d, p, n, sn, scale, mis, pick, rng)
        }
    }
}

/// Next-event estimation toward emissive primitive `lights[pick]` (see [`light_sample`]): a
/// point uniformly by area, weighted against BSDF sampling by MIS.
#[allow(clippy::too_many_arguments)]
fn emitter_light(
    w: &World,
    m: &Material,
    d: Vec3,
    p: Vec3,
    n: Vec3,
    sn: Vec3,
    scale: f32,
    mis: bool,
    pick: u32,
    rng: &mut Rng,
) -> LightSample {
    let features = w.scene.features;
    let light = w.light(pick);
    let (u1, u2) = (rng.next_f32(), rng.next_f32());
    let (q, nl, light_scale) = w.sample_point(light, u1, u2);
    let to = q - p;
    let dist = to.length();
    let wi = to / dist;
    let cos_l = World::light_cos(nl, wi);
    if cos_l <= 0.0 || dist.is_nan() || dist <= 0.0 {
        return LightSample::NONE;
    }
    // The light must lie above both the shading and the geometric surface (eval says zero).
    let (f_cos, pdf_bsdf) = material::eval(m, d, wi, n, sn, features);
    if max3(f_cos) <= 0.0 {
        return LightSample::NONE;
    }
    let pdf_light = w.light_pdf(light, dist, cos_l);
    let weight = if mis {
        sampling::power_heuristic(pdf_light, pdf_bsdf)
    } else {
        1.0
    };
    let le = if w.scene.is_triangle(light.prim) {
        let (b1, b2) = sampling::uniform_triangle(u1, u2);
        let uv = shading::uv_at(w.objects, w.attrs, light.object, light.prim, b1, b2);
        shading::emission_at(&w.material(light), uv, w.textures, w.texels, features)
    } else {
        xyz(w.material(light).emission)
    };
    // Both ends offset off their surfaces; the shadow ray runs over t in (0, 1).
    let from = offset_origin(p, n, scale);
    let to_side = if nl.dot(wi) < 0.0 { nl } else { -nl };
    let target = offset_origin(q, to_side, light_scale);
    LightSample {
        from,
        dir: target - from,
        t_max: 1.0,
        value: f_cos * le * (weight / pdf_light),
    }
}

/// Next-event estimation toward the environment map (see [`light_sample`]): a direction by
/// the map's alias table, a shadow ray to infinity, weighted against BSDF sampling by MIS.
#[allow(clippy::too_many_arguments)]
fn env_light(
    w: &World,
    m: &Material,
    d: Vec3,
    p: Vec3,
    n: Vec3,
    sn: Vec3,
    scale: f32,
    mis: bool,
    rng: &mut Rng,
) -> LightSample {
    if !w.has_env() {
        return LightSample::NONE;
    }
    let s = w
        .env()
        .sample(rng.next_f32(), rng.next_f32(), rng.next_f32(), rng.next_f32());
    if s.pdf <= 0.0 || s.pdf.is_nan() {
        return LightSample::NONE;
    }
    let (f_cos, pdf_bsdf) = material::eval(m, d, s.dir, n, sn, w.scene.features);
    if max3(f_cos) <= 0.0 {
        return LightSample::NONE;
    }
    let pdf_light = w.env_prob() * s.pdf;
    let weight = if mis {
        sampling::power_heuristic(pdf_light, pdf_bsdf)
    } else {
        1.0
    };
    LightSample {
        from: offset_origin(p, n, scale),
        dir: s.dir,
        t_max: f32::INFINITY,
        value: f_cos * s.radiance * (weight / pdf_light),
    }
}

/// The unit direction toward punctual light `l` from point `p` (geometric normal `n` on the
/// path's side, `scale` its primitive's), and the shadow ray toward it with, as its value,
/// the irradiance it brings there on a surface facing it: zero behind the surface or outside
/// a spot's cone. A spot fades
/// from `cos_inner` to `cos_outer` as glTF's `KHR_lights_punctual` recommends (the square of
/// a linear ramp in the cosine).
fn punctual_light(l: &PunctualLight, p: Vec3, n: Vec3, scale: f32) -> (Vec3, LightSample) {
    let from = offset_origin(p, n, scale);
    let (wi, to, t_max, mut e) = if l.kind == LIGHT_DIRECTIONAL {
        let wi = -xyz(l.direction);
        (wi, wi, f32::INFINITY, xyz(l.intensity))
    } else {
        let to = xyz(l.position) - from;
        let d2 = to.length_squared();
        (to / crate::math::sqrt(d2), to, 1.0, xyz(l.intensity) / d2)
    };
    if l.kind == LIGHT_SPOT {
        let (cos_outer, cos_inner) = (l.direction[3], l.intensity[3]);
        let ramp = ((-wi.dot(xyz(l.direction)) - cos_outer) / (cos_inner - cos_outer).max(1e-3)).clamp(0.0, 1.0);
        e *= ramp * ramp;
    }
    if wi.dot(n) <= 0.0 || !finite3(e) || max3(e) <= 0.0 {
        return (wi, LightSample::NONE);
    }
    let s = LightSample {
        from,
        dir: to,
        t_max,
        value: e,
    };
    (wi, s)
}

/// The switches of the bounce loop, read once per invocation.
#[derive(Copy, Clone)]
struct Mode {
    nee: bool,
    mis: bool,
    roulette: bool,
}

impl Mode {
    fn of(w: &World) -> Mode {
        let f = w.frame;
        let lights = w.light_count() > 0 || w.env_prob() > 0.0;
        let nee = w.scene.features & FEATURE_NEE != 0 && f.flags & FLAG_NEE != 0 && lights;
        Mode {
            nee,
            mis: nee && f.flags & FLAG_MIS != 0,
            roulette: f.flags & FLAG_RUSSIAN_ROULETTE != 0,
        }
    }
}

/// A path in flight: the ray it continues along and what its earlier bounces carry.
#[derive(Copy, Clone)]
struct Path {
    origin: Vec3,
    dir: Vec3,
    /// Radiance gathered so far, and the throughput of the bounces behind.
    l: Vec3,
    beta: Vec3,
    /// In a scene in two levels, what next-event estimation brought, apart from `l`
    /// ([`Path::radiance`]: the sum a shadow queue's resolve makes too).
    nee: Vec3,
    /// The last scattering: its direction's density and whether it was diffuse (for MIS).
    prev_pdf: f32,
    prev_diffuse: bool,
    depth: u32,
    rays: u32,
    /// Radiance the first segment brought: the first hit's emission, or the sky (the
    /// denoiser filters only the rest).
    emitted: Vec3,
    /// The ray cone's width where the ray starts and the angle it opens by (texture level of
    /// detail, `crate::texture`).
    cone_width: f32,
    cone_spread: f32,
}

impl Path {
    fn new(origin: Vec3, dir: Vec3, spread: f32) -> Path {
        Path {
            cone_width: 0.0,
            cone_spread: spread,
            origin,
            dir,
            l: Vec3::ZERO,
            nee: Vec3::ZERO,
            emitted: Vec3::ZERO,
            beta: Vec3::ONE,
            prev_pdf: 0.0,
            prev_diffuse: false,
            depth: 0,
            rays: 0,
        }
    }

    /// After a segment has added what its hit emits: the first segment's radiance is the
    /// path's emitted part, and with `capture` its hit goes to `first`.
    fn first_segment_ends(&mut self, capture: bool, found: Found, first: &mut Found) {
        if self.depth == 0 {
            self.emitted = self.l;
            if capture {
                *first = found;
            }
        }
    }

    /// The path's radiance: `l`, and in a scene in two levels with next-event estimation
    /// what the shadow rays brought, added last as [`resolve_pixel`] adds it.
    fn radiance(&self, w: &World) -> Vec3 {
        let f = w.scene.features;
        if f & FEATURE_INSTANCES != 0 && f & FEATURE_NEE != 0 {
            self.l + self.nee
        } else {
            self.l
        }
    }
}

/// One segment of path `q` (which has `q.depth < max_depth`): trace it, add what it sees,
/// scatter. Returns whether the path goes on. With `capture` (the first segment of a
/// pixel's first sample, with [`FEATURE_GUIDES`]) its hit goes to `first`.
///
/// Where next-event estimation's shadow ray is cast is chosen by measurement (H100,
/// bench/NOTES sessions 31-32): a flattened scene's here, after the path has scattered, when
/// only the path's own state is live beside the walk (real-time frames with NEE 2-11% faster,
/// the thesis frame of the flattened sixteen bunnies 8%); a scene in two levels' by
/// [`Trace::shadow`] in [`segment`], which on the GPU queues it for a pass of its own
/// ([`queue_pixel`], [`resolve_pixel`]) and on the CPU executor casts it there. Each
/// specialisation keeps one of the two sites: each site of `Trace::any` inlines a traversal
/// (a second one cost the bunny frame 13%, session 17).
#[allow(clippy::too_many_arguments)]
fn bounce<T: Trace>(
    w: &World,
    tr: &mut T,
    mode: Mode,
    q: &mut Path,
    rng: &mut Rng,
    capture: bool,
    first: &mut Found,
) -> bool {
    let mut shadow = LightSample::NONE;
    let goes_on = segment(w, tr, mode, q, rng, capture, first, &mut shadow);
    if max3(shadow.value) > 0.0 && !tr.any(w, shadow.from, shadow.dir, shadow.t_max) {
        q.l += shadow.value;
    }
    goes_on
}

/// [`bounce`] but for a flattened scene's shadow ray, which goes to `shadow` (its value
/// weighted by the path's throughput) for `bounce` to cast; a scene in two levels' goes to
/// [`Trace::shadow`], its value to [`Path::nee`].
#[allow(clippy::too_many_arguments)]
fn segment<T: Trace>(
    w: &World,
    tr: &mut T,
    mode: Mode,
    q: &mut Path,
    rng: &mut Rng,
    capture: bool,
    first: &mut Found,
    shadow: &mut LightSample,
) -> bool {
    let found = tr.found(w, q.origin, q.dir, f32::INFINITY);
    shade(w, tr, mode, q, rng, capture, first, shadow, found)
}

/// The rest of [`segment`] once its ray has found `found`: what it sees, and the scatter.
#[allow(clippy::too_many_arguments)]
fn shade<T: Trace>(
    w: &World,
    tr: &mut T,
    mode: Mode,
    q: &mut Path,
    rng: &mut Rng,
    capture: bool,
    first: &mut Found,
    shadow: &mut LightSample,
    found: Found,
) -> bool {
    let f = w.frame;
    let (o, d) = (q.origin, q.dir);
    let hit = found.hit;
    q.rays += 1;
    if hit.prim == INVALID {
        // Paths that next-event estimation also reaches toward the map count with their MIS
        // weight (without MIS, not at all: next-event estimation counts them).
        let env_prob = w.env_prob();
        let weight = if !(q.prev_diffuse && mode.nee && env_prob > 0.0) {
            1.0
        } else if mode.mis {
            sampling::power_heuristic(q.prev_pdf, env_prob * w.env().pdf(d))
        } else {
            0.0
        };
        q.l += q.beta * sky(w, d) * weight;
        if q.depth == 0 {
            q.emitted = q.l;
        }
        return false;
    }
    let material = w.material(found.at);
    // The last segment sees only what its surface emits, and a material without emission
    // (whose texture can only scale it) emits nothing: its surface is not shaded.
    let last = q.depth + 1 >= f.max_depth;
    if last && xyz(material.emission) == Vec3::ZERO {
        q.first_segment_ends(capture, found, first);
        return false;
    }
    let mut sp = shading::surface_point(&w.scene, w.objects, w.attrs, found.at, o, d, &hit);
    let cone_width = q.cone_width + q.cone_spread * hit.t;
    let m = shading::textured(
        &material,
        &mut sp,
        d,
        cone_width,
        w.textures,
        w.texels,
        w.scene.features,
    );
    let (p, ng, scale) = (sp.p, sp.ng, sp.scale);
    let le = xyz(m.emission);
    let cos_l = World::light_cos(ng, d);
    if max3(le) > 0.0 && cos_l > 0.0 {
        // Paths that next-event estimation also reaches count with their MIS weight.
        let weight = if !(q.prev_diffuse && mode.nee) {
            1.0
        } else if mode.mis {
            sampling::power_heuristic(q.prev_pdf, w.light_pdf(found.at, hit.t, cos_l))
        } else {
            0.0
        };
        q.l += q.beta * le * weight;
    }
    q.first_segment_ends(capture, found, first);
    // The last segment scatters nowhere: its bounce, light sample and roulette would end
    // with the path, and nothing reads its random stream after it (each sample seeds its
    // own), so they are not drawn: the same image.
    if last {
        return false;
    }
    let s = material::scatter(&m, d, ng, sp.ns, w.scene.features, rng);
    // Next-event estimation lights every non-delta surface, whether or not the direction
    // the BSDF sampled goes on (a GGX sample below the surface ends the path, not the light).
    if s.diffuse && mode.nee {
        let (side, shading_side) = facing(d, ng, sp.ns);
        let l = light_sample(w, &m, d, p, side, shading_side, scale, mode.mis, rng);
        if w.scene.features & FEATURE_INSTANCES != 0 {
            if max3(l.value) > 0.0 {
                q.nee += tr.shadow(w, l.from, l.dir, l.t_max, q.beta * l.value);
            }
        } else {
            *shadow = LightSample {
                value: q.beta * l.value,
                ..l
            };
        }
        q.rays += 1;
    }
    if s.absorbed {
        return false;
    }
    q.beta *= s.weight;
    q.origin = leave(p, ng, scale, s.dir);
    q.dir = s.dir;
    q.prev_pdf = s.pdf;
    q.prev_diffuse = s.diffuse;
    q.depth += 1;
    // The cone goes on from the hit; a rough bounce opens it (a texture seen through a
    // diffuse reflection needs little detail): by a radian after Lambert, by GGX's alpha.
    q.cone_width = cone_width;
    if s.diffuse {
        q.cone_spread += if m.kind == MaterialKind::Pbr as u32 {
            m.roughness * m.roughness
        } else {
            1.0
        };
    }
    if mode.roulette && q.depth >= ROULETTE_AFTER {
        let survive = max3(q.beta).min(0.95);
        if rng.next_f32() >= survive {
            return false;
        }
        q.beta /= survive;
    }
    true
}

/// Work items a dispatch of the persistent stepped loop aims at ([`sample_groups`]): a lane
/// takes an item (a pixel's samples, or a group of them) and traces all of it before it takes
/// the next, so once the items run out the lanes end at times spread over a whole item's
/// work. With about 135K lanes (an H200) and 800x800 pixels a lane traced five pixels, and the
/// frame 8-13% slower than the same samples over 3200x3200 pixels; in groups, H200, 800x800
/// at 32 spp, depth 16: the closed box 74.9 -> 72.0 ms, the bunny without NEE 13.4 -> 12.3,
/// the sixteen bunnies 33.3-34.2 -> 28.4. Not for the segment loop's frames (with NEE): the
/// Cornell box's cheap paths then waited on the one counter's six times as many atomics, 16.9
/// -> 18.4 ms (bench/NOTES.md, session 61).
pub const GROUP_ITEMS: u32 = 1 << 22;

/// The most groups a pixel's samples of a dispatch are split into.
pub const MAX_GROUPS: u32 = 32;

/// Groups a persistent stepped dispatch of `samples` samples of `pixels` pixels splits each pixel's
/// samples into: enough for about [`GROUP_ITEMS`] items, at most [`MAX_GROUPS`], none empty.
/// From the frame alone, not the device, so that every device sums the same groups (the
/// image's bits: [`add_groups`]).
pub fn sample_groups(pixels: u32, samples: u32) -> u32 {
    let want = (GROUP_ITEMS / pixels.max(1)).clamp(1, MAX_GROUPS).min(samples.max(1));
    let per = samples.div_ceil(want).max(1);
    samples.div_ceil(per).max(1)
}

/// Group `g`'s samples of a dispatch of `samples` samples in `groups` groups: the first
/// (from the dispatch's first) and how many.
pub fn group_samples(samples: u32, groups: u32, g: u32) -> (u32, u32) {
    let per = samples.div_ceil(groups.max(1));
    let first = (g * per).min(samples);
    (first, per.min(samples - first))
}

/// Where group `g`'s sums of pixel `pixel` are written, past the frame's `pixels` sums.
pub fn group_slot(pixels: u32, g: u32, pixel: u32) -> u32 {
    pixels * (1 + g) + pixel
}

/// Adds pixel `pixel`'s `groups` group sums (written by a dispatch of `groups` groups) to
/// its accumulation: the groups' sums added in group order, then to what the pixel held (as
/// a dispatch of one group adds its samples' sum). The host's `Kernel::AccumGroups`, after
/// such a dispatch.
pub fn add_groups(pixel: u32, pixels: u32, groups: u32, accum: &mut [[f32; 4]]) {
    if pixel >= pixels {
        return;
    }
    let mut s = *sync::at(accum, group_slot(pixels, 0, pixel));
    let mut g = 1;
    while g < groups {
        let t = *sync::at(accum, group_slot(pixels, g, pixel));
        s = [s[0] + t[0], s[1] + t[1], s[2] + t[2], s[3] + t[3]];
        g += 1;
    }
    let a = sync::at_mut(accum, pixel);
    *a = [a[0] + s[0], a[1] + s[1], a[2] + s[2], a[3] + s[3]];
}

/// Persistent path tracing (the host's `Kernel::PathTracePersistent`, workgroups of 1,024):
/// every invocation renders pixel after pixel ([`render_pixel`]), each the next number of a
/// counter (the first word of `guides`' last entry, zeroed before the dispatch), until the
/// frame has none left. Numbers run through tiles of 8x4 pixels, 32 to a tile, so the lanes
/// of a warp that take numbers together trace neighbouring pixels, as in the 8x8 tiles of
/// `path_trace`. Every pixel is rendered once, whichever invocation takes it.
pub fn render_tiles<T: Trace>(
    p: &RenderPush,
    w: &World,
    tr: &mut T,
    accum: &mut [[f32; 4]],
    guides: &mut [[u32; 4]],
    image: &mut [u32],
) {
    let f = w.frame;
    let tiles_x = f.width.div_ceil(8);
    let n = tiles_x * f.height.div_ceil(4) * 32;
    let last = guides.len() as u32 - 1;
    loop {
        let i = sync::atomic_add_device::<false>(&mut sync::at_mut(guides, last)[0], 1);
        if i >= n {
            return;
        }
        let (tile, lane) = (i / 32, i % 32);
        let (x, y) = ((tile % tiles_x) * 8 + lane % 8, (tile / tiles_x) * 4 + lane / 8);
        render_pixel(x, y, p, w, tr, accum, guides, image);
    }
}

/// [`render_tiles`] for the shadow queue: the pixels of the band `p.row_base..p.row_base +
/// p.rows`, each queued ([`queue_pixel`]). (Its own copy of the loop: the path tracer's kernels
/// keep the code they were measured with.)
pub fn queue_tiles(p: &RenderPush, w: &World, guides: &mut [[u32; 4]], queue: &mut [[f32; 4]]) {
    let f = w.frame;
    let tiles_x = f.width.div_ceil(8);
    let n = tiles_x * p.rows.div_ceil(4) * 32;
    let last = guides.len() as u32 - 1;
    loop {
        let i = sync::atomic_add_device::<false>(&mut sync::at_mut(guides, last)[0], 1);
        if i >= n {
            return;
        }
        let (tile, lane) = (i / 32, i % 32);
        let (x, y) = (
            (tile % tiles_x) * 8 + lane % 8,
            p.row_base + (tile / tiles_x) * 4 + lane / 8,
        );
        queue_pixel(x, y, p, w, guides, queue);
    }
}

/// Where slot `k` of band pixel `i` starts in the shadow queue of a band of `band` pixels:
/// the queue holds two planes of the paths' sums (`i`: radiance without next-event
/// estimation and rays; `band + i`: the first hit's emission and the slots queued), then
/// per slot three planes (the ray's origin and `t_max`, its direction, its value), each
/// `band` entries, so that a warp's lanes read neighbouring entries.
pub fn queue_slot(band: u32, k: u32, i: u32) -> u32 {
    (2 + 3 * k) * band + i
}

/// Entries of the shadow queue of a band of `band` pixels with paths of at most `max_depth`
/// segments (next-event estimation queues at most one shadow ray a segment but the last).
pub fn queue_entries(band: u32, max_depth: u32) -> u64 {
    (2 + 3 * max_depth.saturating_sub(1) as u64) * band as u64
}

/// The path tracer's pass of the shadow queue (`path_queue`, `path_queue_persistent`: the
/// host's choice for a scene in two levels with next-event estimation on the GPU): sample
/// `p.sample_base` of pixel `(x, y)` of the band `p.row_base..p.row_base + p.rows` traced as
/// [`pixel_samples_guided`] traces it, its shadow rays queued rather than cast (`queue`, see
/// [`queue_slot`]); the frame's first dispatch also writes the pixel's guide (its sums zero).
/// [`resolve_pixel`] casts the shadow rays and adds the sample. Splitting them keeps the
/// walk's registers of the shadow rays out of the path tracer's (H100, bench/NOTES session
/// 32: real-time NEE frames in two levels 23-26% faster).
pub fn queue_pixel(x: u32, y: u32, p: &RenderPush, w: &World, guides: &mut [[u32; 4]], queue: &mut [[f32; 4]]) {
    let f = w.frame;
    if x >= f.width || y < p.row_base || y >= p.row_base + p.rows || y >= f.height {
        return;
    }
    let band = p.rows * f.width;
    let i = (y - p.row_base) * f.width + x;
    let pixel = y * f.width + x;
    let guided = w.scene.features & FEATURE_GUIDES != 0;
    let mut tr = Queued {
        pending: false,
        from: Vec3::ZERO,
        dir: Vec3::ZERO,
        t_max: 0.0,
        value: Vec3::ZERO,
    };
    let mode = Mode::of(w);
    let mut rng = Rng::new(pixel, p.sample_base, f.seed);
    let (o, d) = camera_ray(&f.camera, f.width, f.height, x, y, w.scene.features, &mut rng);
    let mut q = Path::new(o, d, f.pixel_spread);
    let mut first = Found::MISS;
    let mut queued = 0;
    let mut live = f.max_depth > 0;
    while live {
        let capture = guided && q.depth == 0;
        live = bounce(w, &mut tr, mode, &mut q, &mut rng, capture, &mut first);
        if tr.pending {
            let slot = queue_slot(band, queued, i);
            let (o, d, v) = (tr.from, tr.dir, tr.value);
            *sync::at_mut(queue, slot) = [o.x, o.y, o.z, tr.t_max];
            *sync::at_mut(queue, slot + band) = [d.x, d.y, d.z, 0.0];
            *sync::at_mut(queue, slot + 2 * band) = [v.x, v.y, v.z, 0.0];
            tr.pending = false;
            queued += 1;
        }
    }
    *sync::at_mut(queue, i) = [q.l.x, q.l.y, q.l.z, q.rays as f32];
    *sync::at_mut(queue, band + i) = [q.emitted.x, q.emitted.y, q.emitted.z, queued as f32];
    if guided && p.count == 0 {
        let g = if f.max_depth > 0 {
            first_hit_guide(x, y, p, w, &first)
        } else {
            Guide::NONE
        };
        g.store(guides, f.width * f.height, pixel);
    }
}

/// `shadow_resolve`: the shadow rays [`queue_pixel`] queued for band pixel `i` cast in order,
/// the lit ones' values added to the path's radiance (as [`Path::radiance`] adds them), and
/// the sample added to `accum` (and the guide's sums) as [`render_pixel`] adds a sample.
pub fn resolve_pixel<T: Trace>(
    i: u32,
    p: &RenderPush,
    w: &World,
    tr: &mut T,
    accum: &mut [[f32; 4]],
    guides: &mut [[u32; 4]],
    queue: &[[f32; 4]],
) {
    let f = w.frame;
    let band = p.rows * f.width;
    if i >= band {
        return;
    }
    let slots = sync::at(queue, band + i)[3] as u32;
    let mut nee = Vec3::ZERO;
    let mut k = 0;
    while k < slots {
        let slot = queue_slot(band, k, i);
        let (o, d) = (*sync::at(queue, slot), *sync::at(queue, slot + band));
        if !tr.any(w, xyz(o), xyz(d), o[3]) {
            nee += xyz(*sync::at(queue, slot + 2 * band));
        }
        k += 1;
    }
    add_resolved(i, nee, p, w, accum, guides, queue);
}

/// `shadow_resolve_persistent` (scenes in two levels, whose queue only it resolves):
/// [`resolve_pixel`] for pixel after pixel of the band, each the next number of the counter
/// of [`render_tiles`], but a lane whose shadow ray ends starts its next ray (the pixel's
/// next slot, or the first of the next pixel with any) at once, in the walk's own loop
/// ([`traverse::Levels`]), instead of waiting for the warp's longest walk to end (Aila and
/// Laine 2009's persistent traversal with rays fetched as lanes finish). The same rays,
/// lit values added in the same order: the same bits as [`resolve_pixel`].
pub fn resolve_tiles(p: &RenderPush, w: &World, accum: &mut [[f32; 4]], guides: &mut [[u32; 4]], queue: &[[f32; 4]]) {
    let f = w.frame;
    let band = p.rows * f.width;
    let last = guides.len() as u32 - 1;
    let mut walk = traverse::Levels::new();
    // The band pixel resolved (INVALID: none yet), its slots, the next slot to cast.
    let mut i = INVALID;
    let (mut slots, mut k) = (0, 0);
    let mut nee = Vec3::ZERO;
    // Whether slot `k`'s ray is cast, and still walking.
    let (mut cast, mut walking) = (false, false);
    loop {
        if walking {
            walking = walk.step::<true>(&w.scene);
        } else {
            if cast {
                if walk.best.prim == INVALID {
                    nee += xyz(*sync::at(queue, queue_slot(band, k, i) + 2 * band));
                }
                k += 1;
                cast = false;
            }
            if k < slots {
                let slot = queue_slot(band, k, i);
                let (o, d) = (*sync::at(queue, slot), *sync::at(queue, slot + band));
                walking = walk.start(&w.scene, xyz(o), xyz(d), o[3]);
                cast = true;
            } else {
                if i != INVALID {
                    add_resolved(i, nee, p, w, accum, guides, queue);
                }
                i = sync::atomic_add_device::<false>(&mut sync::at_mut(guides, last)[0], 1);
                if i >= band {
                    return;
                }
                slots = sync::at(queue, band + i)[3] as u32;
                k = 0;
                nee = Vec3::ZERO;
            }
        }
    }
}

/// Adds band pixel `i`'s sample to `accum` (and the guide's sums) as [`render_pixel`] adds a
/// sample: its path's radiance without next-event estimation from the queue plus `nee`, the
/// lit values of its shadow rays.
fn add_resolved(
    i: u32,
    nee: Vec3,
    p: &RenderPush,
    w: &World,
    accum: &mut [[f32; 4]],
    guides: &mut [[u32; 4]],
    queue: &[[f32; 4]],
) {
    let f = w.frame;
    let band = p.rows * f.width;
    let pixel = p.row_base * f.width + i;
    let (sums, emitted) = (*sync::at(queue, i), *sync::at(queue, band + i));
    let l = xyz(sums) + nee;
    let lit = finite3(l);
    let s = if lit { l } else { Vec3::ZERO };
    let a = sync::at_mut(accum, pixel);
    *a = [a[0] + s.x, a[1] + s.y, a[2] + s.z, a[3] + sums[3]];
    if w.scene.features & FEATURE_GUIDES != 0 {
        let e = if lit { xyz(emitted) } else { Vec3::ZERO };
        let g = Guide {
            color: (s - e).into(),
            emission: e.into(),
            ..Guide::NONE
        };
        Guide::add_sums(&g, guides, f.width * f.height, pixel);
    }
}

/// Steps of [`stepped_pixels`]'s walks between two votes: a vote every step made its frames
/// 5-9% slower than a vote every 8 on the H200 (every 2 and 4 in between).
const STEPS_A_VOTE: u32 = 8;

/// The stepped path loop (the host's `Kernel::PathStepped`: `fetch` false, pixel `(x, y)`'s
/// samples returned; `Kernel::PathSteppedPersistent`: `fetch`, pixel after pixel from the
/// counter as [`render_tiles`] takes them, each added to `accum` and `guides` as
/// [`render_pixel`] adds it, nothing returned), with the walk's
/// steps in its own inner loop ([`traverse::Flat`]): lanes whose walks have ended wait until
/// half of the subgroup's lanes have (voting every [`STEPS_A_VOTE`] steps), then shade what
/// they found and start their next walks (the path's next segment, the pixel's next sample,
/// the next pixel), while the lanes still walking go back to their steps. So a subgroup does
/// not idle at every segment until its longest walk ends (CPU count, 8x4 lanes: 19-28% of the
/// lanes of a segment-at-a-time loop walk in an average step of the bunny's or the closed
/// box's diffuse bounces), nor run its shading for one or two lanes at a time (Aila & Laine
/// 2009's persistent while-while with rays fetched as lanes finish). Each lane's paths are
/// traced and shaded exactly as by [`segment_samples`], whichever lanes share its subgroup:
/// the same image. On the H200 the bunny's and the closed box's frames of 4-16 segments trace
/// 9-16% faster; primary rays alone 23% slower (their lanes walk alike, and shading half a
/// subgroup at a time costs more than the waits it saves), hence frames of more than one
/// segment only (bench/NOTES.md, session 51). For what the host marks
/// [`crate::types::VARIANT_STEPPED`]: a flattened scene through the binary BVH (or by brute
/// force) without next-event estimation, each segment one closest-hit walk. Kernels of their
/// own, so that the segment loop's kernels hold one loop (lavapipe compiles a module's dead
/// branches too: bench/NOTES.md, session 52).
#[allow(clippy::too_many_arguments)]
fn stepped_pixels(
    x: u32,
    y: u32,
    fetch: bool,
    p: &RenderPush,
    w: &World,
    accum: &mut [[f32; 4]],
    guides: &mut [[u32; 4]],
    image: &mut [u32],
) -> ([f32; 4], Guide) {
    let f = w.frame;
    let guided = w.scene.features & FEATURE_GUIDES != 0;
    let mode = Mode::of(w);
    let tiles_x = f.width.div_ceil(8);
    let n = tiles_x * f.height.div_ceil(4) * 32;
    let (mut x, mut y) = (x, y);
    // Fetched items are a pixel's samples, or with `VARIANT_GROUPS` a group of them
    // ([`sample_groups`]): the item's group, its first sample and how many.
    let grouped = fetch && w.scene.features & VARIANT_GROUPS != 0;
    let groups = if grouped { p.flags.max(1) } else { 1 };
    let (mut group, mut base, mut count) = (0, p.sample_base, p.samples);
    // The pixel's samples so far (`open`: a pixel is held), as in `pixel_samples_guided`.
    let mut open = !fetch;
    let (mut sum, mut emission, mut rays, mut started) = (Vec3::ZERO, Vec3::ZERO, 0, 0);
    let mut first = Found::MISS;
    // The path in flight (`live`) and its segment's walk (`walking`).
    let mut q = Path::new(Vec3::ZERO, Vec3::Z, 0.0);
    let mut rng = Rng::new(0, 0, f.seed);
    let mut live = false;
    let mut walk = traverse::Flat::new();
    let mut walking = false;
    loop {
        // Steps until half of the subgroup's lanes wait: a tight loop that does not touch the
        // path's state, voting every `STEPS_A_VOTE` steps (every lane in the loop takes part;
        // the lanes in it do not change, so they are counted once before it). The steps'
        // count is tested at the end of the loop, not as a `while` at its top: there NVIDIA's
        // compiler copied the walk's state through a second set of registers every step
        // (H200: the closed box 86.8 -> 79.7 ms; bench/NOTES.md, session 54).
        let lanes = sync::count_waiting(true);
        loop {
            let mut k = 0;
            loop {
                if walking {
                    walking = walk.step(&w.scene);
                }
                k += 1;
                if k == STEPS_A_VOTE {
                    break;
                }
            }
            if 2 * sync::count_waiting(!walking) >= lanes {
                break;
            }
        }
        if walking {
            continue;
        }
        if live {
            let hit = walk.hit();
            let found = if hit.prim == INVALID {
                Found::MISS
            } else {
                Found {
                    hit,
                    at: Placed::hit(w.scene.instances, w.prim_object, INVALID, hit.prim),
                }
            };
            let capture = guided && started == 1 && q.depth == 0;
            let mut shadow = LightSample::NONE;
            live = shade(
                w,
                &mut Walk,
                mode,
                &mut q,
                &mut rng,
                capture,
                &mut first,
                &mut shadow,
                found,
            );
            if !live {
                let l = q.radiance(w);
                if finite3(l) {
                    sum += l;
                    if guided {
                        emission += q.emitted;
                    }
                }
                rays += q.rays;
            }
        }
        if !live {
            if !open || started == count {
                if open {
                    let (s, g) = pixel_result(x, y, p, w, &first, sum, emission, rays);
                    if !fetch {
                        return (s, g);
                    }
                    if grouped {
                        let slot = group_slot(f.width * f.height, group, y * f.width + x);
                        *sync::at_mut(accum, slot) = s;
                    } else {
                        add_pixel(y * f.width + x, s, &g, p, w, accum, guides, image);
                    }
                }
                // The next pixel of the frame (numbered through tiles of 8x4, as
                // `render_tiles` takes them), if any.
                let last = guides.len() as u32 - 1;
                let mut i = sync::atomic_add_device::<false>(&mut sync::at_mut(guides, last)[0], 1);
                let items = if grouped { n * groups } else { n };
                loop {
                    let j = if grouped { i % n } else { i };
                    let (tile, lane) = (j / 32, j % 32);
                    (x, y) = ((tile % tiles_x) * 8 + lane % 8, (tile / tiles_x) * 4 + lane / 8);
                    if i >= items || (x < f.width && y < f.height) {
                        break;
                    }
                    i = sync::atomic_add_device::<false>(&mut sync::at_mut(guides, last)[0], 1);
                }
                if i >= items {
                    return (Default::default(), Guide::NONE);
                }
                if grouped {
                    group = i / n;
                    let (first_sample, c) = group_samples(p.samples, groups, group);
                    (base, count) = (p.sample_base + first_sample, c);
                }
                open = true;
                (sum, emission, rays, started) = (Vec3::ZERO, Vec3::ZERO, 0, 0);
                first = Found::MISS;
                if count == 0 {
                    continue;
                }
            }
            rng = Rng::new(y * f.width + x, base + started, f.seed);
            let (o, d) = camera_ray(&f.camera, f.width, f.height, x, y, w.scene.features, &mut rng);
            q = Path::new(o, d, f.pixel_spread);
            started += 1;
            if f.max_depth == 0 {
                // A sample of no segments adds nothing.
                continue;
            }
            live = true;
        }
        // The walk, or without the BVH the brute force (`FLAG_BVH`) at once.
        walking = if w.bvh() {
            walk.start(&w.scene, q.origin, q.dir, f32::INFINITY)
        } else {
            walk.set_hit(traverse::closest_brute(&w.scene, q.origin, q.dir, f32::INFINITY));
            false
        };
    }
}

/// Adds `p.samples` samples of pixel `(x, y)` to `accum`: see [`pixel_samples`]. With
/// [`FEATURE_GUIDES`] also the pixel's guide: written by the frame's first dispatch
/// (`p.count == 0`, the samples the frame traced before), its sums added to by the rest.
/// With [`DISPLAY_IN_TRACE`] the samples are written, not added, and displayed to `image`.
#[allow(clippy::too_many_arguments)]
pub fn render_pixel<T: Trace>(
    x: u32,
    y: u32,
    p: &RenderPush,
    w: &World,
    tr: &mut T,
    accum: &mut [[f32; 4]],
    guides: &mut [[u32; 4]],
    image: &mut [u32],
) {
    let f = w.frame;
    if x >= f.width || y >= f.height {
        return;
    }
    let (s, g) = segment_samples(x, y, p, w, tr);
    add_pixel(y * f.width + x, s, &g, p, w, accum, guides, image);
}

/// [`render_pixel`] through the stepped loop ([`stepped_pixels`]): the host's
/// `Kernel::PathStepped`, 8x8 tiles of an invocation a pixel.
pub fn stepped_pixel(
    x: u32,
    y: u32,
    p: &RenderPush,
    w: &World,
    accum: &mut [[f32; 4]],
    guides: &mut [[u32; 4]],
    image: &mut [u32],
) {
    let f = w.frame;
    if x >= f.width || y >= f.height {
        return;
    }
    let (s, g) = stepped_pixels(x, y, false, p, w, accum, guides, image);
    add_pixel(y * f.width + x, s, &g, p, w, accum, guides, image);
}

/// [`render_tiles`] through the stepped loop ([`stepped_pixels`]): the host's
/// `Kernel::PathSteppedPersistent`.
pub fn stepped_tiles(p: &RenderPush, w: &World, accum: &mut [[f32; 4]], guides: &mut [[u32; 4]], image: &mut [u32]) {
    stepped_pixels(0, 0, true, p, w, accum, guides, image);
}

/// [`pixel_samples_guided`] through the stepped loop, on the CPU (one lane a subgroup: the
/// tests compare the two loops' bits).
#[cfg(not(target_arch = "spirv"))]
pub fn stepped_samples(x: u32, y: u32, p: &RenderPush, w: &World) -> ([f32; 4], Guide) {
    stepped_pixels(x, y, false, p, w, &mut [], &mut [], &mut [])
}

/// Adds a pixel's samples `s` (and its guide `g`) to `accum` (and `guides`), or with
/// [`DISPLAY_IN_TRACE`] writes them there and their display code to `image`: see
/// [`render_pixel`].
#[allow(clippy::too_many_arguments)]
fn add_pixel(
    pixel: u32,
    s: [f32; 4],
    g: &Guide,
    p: &RenderPush,
    w: &World,
    accum: &mut [[f32; 4]],
    guides: &mut [[u32; 4]],
    image: &mut [u32],
) {
    let f = w.frame;
    let a = sync::at_mut(accum, pixel);
    if p.flags & DISPLAY_IN_TRACE != 0 {
        *a = s;
        *sync::at_mut(image, pixel) = display::pixel(s, p, f);
    } else {
        *a = [a[0] + s[0], a[1] + s[1], a[2] + s[2], a[3] + s[3]];
    }
    if w.scene.features & FEATURE_GUIDES != 0 {
        let n = f.width * f.height;
        if p.count == 0 {
            g.store(guides, n, pixel);
        } else {
            Guide::add_sums(g, guides, n, pixel);
        }
    }
}

/// Samples `p.sample_base..p.sample_base + p.samples` of pixel `(x, y)`: the sum of their
/// radiance (`xyz`) and the number of rays traced (`w`). Samples whose radiance is not
/// finite are dropped.
///
/// One loop runs every bounce of every sample, starting the next sample's camera ray as soon
/// as a path ends (path regeneration): on a GPU the lanes of a subgroup then trace together
/// until each has finished all its samples, instead of idling at every sample until the
/// subgroup's longest path ends. Each sample keeps its own random stream and samples are
/// summed in order, so the result is the same as tracing them one after another.
#[cfg(not(target_arch = "spirv"))]
pub fn pixel_samples(x: u32, y: u32, p: &RenderPush, w: &World) -> [f32; 4] {
    pixel_samples_guided(x, y, p, w, &mut Walk).0
}

/// [`pixel_samples`], and with [`FEATURE_GUIDES`] the pixel's guide for the denoiser: the
/// samples' radiance split into the first hits' emission and the rest, and the first
/// sample's first hit (`crate::denoise`). Without the feature the guide is `Guide::NONE`.
#[cfg(not(target_arch = "spirv"))]
pub fn pixel_samples_guided<T: Trace>(x: u32, y: u32, p: &RenderPush, w: &World, tr: &mut T) -> ([f32; 4], Guide) {
    segment_samples(x, y, p, w, tr)
}

/// [`pixel_samples_guided`] a segment at a time: each segment's walk to its end, then its
/// shading (the loop of every frame but those [`stepped_pixels`] traces).
fn segment_samples<T: Trace>(x: u32, y: u32, p: &RenderPush, w: &World, tr: &mut T) -> ([f32; 4], Guide) {
    let f = w.frame;
    let guides = w.scene.features & FEATURE_GUIDES != 0;
    // Only the first sample's first hit is kept in the loop; its guide is made after it.
    let mut first = Found::MISS;
    let mut emission = Vec3::ZERO;
    let mode = Mode::of(w);
    let pixel = y * f.width + x;
    let mut sum = Vec3::ZERO;
    let mut rays = 0;
    let mut started = 0;
    let mut q = Path::new(Vec3::ZERO, Vec3::Z, 0.0);
    let mut rng = Rng::new(pixel, p.sample_base, f.seed);
    let mut live = false;
    loop {
        if !live {
            if started == p.samples {
                break;
            }
            rng = Rng::new(pixel, p.sample_base + started, f.seed);
            let (o, d) = camera_ray(&f.camera, f.width, f.height, x, y, w.scene.features, &mut rng);
            q = Path::new(o, d, f.pixel_spread);
            started += 1;
            if f.max_depth == 0 {
                continue;
            }
        }
        let capture = guides && started == 1 && q.depth == 0;
        live = bounce(w, tr, mode, &mut q, &mut rng, capture, &mut first);
        if !live {
            let l = q.radiance(w);
            if finite3(l) {
                sum += l;
                if guides {
                    emission += q.emitted;
                }
            }
            rays += q.rays;
        }
    }
    pixel_result(x, y, p, w, &first, sum, emission, rays)
}

/// A pixel's samples as [`pixel_samples_guided`] returns them, from the sum of their
/// radiance, its part the first hits emit, the rays traced and the first sample's first hit.
#[allow(clippy::too_many_arguments)]
fn pixel_result(
    x: u32,
    y: u32,
    p: &RenderPush,
    w: &World,
    first: &Found,
    sum: Vec3,
    emission: Vec3,
    rays: u32,
) -> ([f32; 4], Guide) {
    let guides = w.scene.features & FEATURE_GUIDES != 0;
    // Only the frame's first dispatch writes the geometry (`render_pixel`).
    let mut guide = if guides && w.frame.max_depth > 0 && p.count == 0 {
        first_hit_guide(x, y, p, w, first)
    } else {
        Guide::NONE
    };
    // What the first hits reflect: the rest of the radiance.
    guide.color = (sum - emission).into();
    guide.emission = emission.into();
    ([sum.x, sum.y, sum.z, rays as f32], guide)
}

/// The denoiser's guide of the first hit `h` of pixel `(x, y)`'s first sample (its camera
/// ray drawn again from the sample's stream): albedo, normal, distance, object and where
/// the point was in the previous frame; [`Guide::NONE`] where the ray left the scene.
fn first_hit_guide(x: u32, y: u32, p: &RenderPush, w: &World, first: &Found) -> Guide {
    let f = w.frame;
    let h = &first.hit;
    if h.prim == INVALID {
        return Guide::NONE;
    }
    let mut rng = Rng::new(y * f.width + x, p.sample_base, f.seed);
    let (o, d) = camera_ray(&f.camera, f.width, f.height, x, y, w.scene.features, &mut rng);
    let mut sp = shading::surface_point(&w.scene, w.objects, w.attrs, first.at, o, d, h);
    let m = shading::textured(
        &w.material(first.at),
        &mut sp,
        d,
        f.pixel_spread * h.t,
        w.textures,
        w.texels,
        w.scene.features,
    );
    let object = first.at.object;
    let (px, py, pd) = denoise::motion(f, w.objects, object, sp.p);
    Guide {
        color: [0.0; 3],
        prev_x: px,
        emission: [0.0; 3],
        prev_y: py,
        albedo: [m.albedo[0], m.albedo[1], m.albedo[2]],
        object,
        normal: denoise::oct_encode(facing(d, sp.ng, sp.ns).1),
        depth: h.t,
        prev_depth: pd,
        _pad: 0,
    }
}

/// Closest hit of ray `i` of `rays` (origin `w`: unused, direction `w`: largest distance).
/// With [`CAST_ANY`] an any-hit query; with [`CAST_OBJECT`] the hit names its object; with [`CAST_SPAWN`] query `i` is the pair of rays
/// `2 i`, `2 i + 1`: see there.
pub fn cast<T: Trace>(i: u32, p: &RenderPush, w: &World, tr: &mut T, rays: &[Ray], hits: &mut [Hit]) {
    if i >= p.count {
        return;
    }
    if p.flags & CAST_SPAWN == 0 {
        let r = rays[i as usize];
        let (o, d) = (xyz(r.origin), xyz(r.dir));
        hits[i as usize] = if p.flags & CAST_OBJECT != 0 {
            let found = tr.found(w, o, d, r.dir[3]);
            Hit {
                prim: found.at.object,
                ..found.hit
            }
        } else if p.flags & CAST_ANY == 0 {
            tr.closest(w, o, d, r.dir[3])
        } else if tr.any(w, o, d, r.dir[3]) {
            Hit {
                t: 0.0,
                prim: 0,
                u: 0.0,
                v: 0.0,
            }
        } else {
            Hit::MISS
        };
        return;
    }
    let (first, second) = (rays[2 * i as usize], rays[2 * i as usize + 1]);
    let (o, d) = (xyz(first.origin), xyz(first.dir));
    let found = tr.found(w, o, d, first.dir[3]);
    let h = found.hit;
    hits[2 * i as usize] = h;
    hits[2 * i as usize + 1] = if h.prim == INVALID {
        Hit::MISS
    } else {
        let (q, ng, scale) = traverse::surface_at(&w.scene, w.objects, found.at, o, d, &h);
        let d2 = xyz(second.dir);
        tr.closest(w, leave(q, ng, scale, d2), d2, second.dir[3])
    };
}
