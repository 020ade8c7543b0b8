//! What a bare model needs to be a scene: a camera framing its bounding sphere, the default sky
//! and a key light. The camera looks at the centre of the bounds from the front (`+z`, where
//! glTF models face), a little from above and from the right, at the distance where the
//! bounding sphere fills the vertical field of view with a margin. The key light is an emissive
//! sphere above the model on the camera's side, sized and bright in proportion to the bounds so
//! that a white diffuse surface facing it reflects about as much as under the sky.
use super::super::{material, Animation, CameraSpec, Scene, SceneObject, Shape, Transform};
use glam::Vec3;

/// The sky of scenes made from a model file: Ray Tracing in One Weekend's blue-to-white sky of
/// the outdoor built-ins, at half their brightness so that the key light casts shadows.
pub const SKY_TOP: Vec3 = Vec3::new(0.25, 0.35, 0.5);
pub const SKY_BOTTOM: Vec3 = Vec3::new(0.5, 0.5, 0.5);

/// Vertical field of view of the automatic camera, in degrees.
const VFOV_DEG: f32 = 40.0;

/// Direction from the model's centre to the automatic camera (normalised when used).
const VIEW_FROM: Vec3 = Vec3::new(0.35, 0.3, 1.0);

/// Radiance of the key light.
const KEY_EMISSION: f32 = 12.0;

/// A placeholder until [`complete`] places the camera.
pub(super) const NO_CAMERA: CameraSpec = CameraSpec {
    position: Vec3::new(0.0, 0.0, 1.0),
    look_at: Vec3::ZERO,
    up: Vec3::Y,
    vfov_deg: VFOV_DEG,
    aperture: 0.0,
    focus_distance: None,
};

/// World-space bounds of every mesh object of `scene` (empty: `lo > hi`).
fn bounds(scene: &Scene) -> (Vec3, Vec3) {
    let mut lo = Vec3::INFINITY;
    let mut hi = Vec3::NEG_INFINITY;
    for o in &scene.objects {
        if let Shape::Mesh(m) = o.shape {
            let matrix = o.transform.matrix();
            for v in scene.meshes[m].tris.iter().flat_map(|t| [t.v0, t.v1, t.v2]) {
                let p = matrix.transform_point3(Vec3::new(v[0], v[1], v[2]));
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
    }
    (lo, hi)
}

fn show(v: Vec3) -> String {
    format!("({:.3}, {:.3}, {:.3})", v.x, v.y, v.z)
}

/// Places the camera unless `has_camera`, sets nothing else that the file gave, and adds a key
/// light when no object emits; says in `warnings` (naming `file`) what it assumed.
pub(super) fn complete(scene: &mut Scene, has_camera: bool, file: &str, warnings: &mut Vec<String>) {
    let (lo, hi) = bounds(scene);
    if !(lo.is_finite() && hi.is_finite() && lo.cmple(hi).all()) {
        return;
    }
    let centre = (lo + hi) / 2.0;
    // A flat or point-like model still gets a camera at a finite distance.
    let radius = ((hi - lo).length() / 2.0)
        .max(1e-3 * centre.abs().max_element())
        .max(1e-6);
    let from = VIEW_FROM.normalize();
    if !has_camera {
        let distance = 1.1 * radius / (VFOV_DEG.to_radians() / 2.0).sin();
        scene.camera = CameraSpec {
            position: centre + distance * from,
            look_at: centre,
            ..NO_CAMERA
        };
        warnings.push(format!(
            "{file}: no camera in the file: looking at the centre {} of the bounds {} .. {} from {}, vfov {VFOV_DEG} degrees",
            show(centre),
            show(lo),
            show(hi),
            show(scene.camera.position)
        ));
    }
    warnings.push(format!(
        "{file}: the default sky for models: top {}, bottom {}",
        show(scene.settings.sky_top),
        show(scene.settings.sky_bottom)
    ));
    let emits = scene.objects.iter().any(|o| {
        scene
            .materials
            .get(o.material as usize)
            .is_some_and(|(_, m)| material::emits(m))
    });
    if emits || !scene.punctual.is_empty() {
        return;
    }
    // Above the model, on the side of the camera (the file's or ours), off to its left.
    let towards_camera = (scene.camera.position - centre).normalize_or_zero();
    let side = Vec3::Y.cross(towards_camera).normalize_or_zero();
    let light_radius = 0.5 * radius;
    let at = centre + radius * (2.0 * Vec3::Y + 1.5 * towards_camera - 1.0 * side);
    scene
        .materials
        .push(("key light".to_string(), material::emissive([KEY_EMISSION; 3])));
    scene.objects.push(SceneObject {
        name: "key light".to_string(),
        shape: Shape::Sphere { radius: light_radius },
        transform: Transform::at(at),
        material: scene.materials.len() as u32 - 1,
        animation: Animation::default(),
        instance: None,
    });
    warnings.push(format!(
        "{file}: nothing in the file emits light: added a key light, a sphere of radius {light_radius:.3} and radiance {KEY_EMISSION} at {}",
        show(at)
    ));
}
