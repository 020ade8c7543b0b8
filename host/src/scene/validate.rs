//! Range checks of a finished scene, the same for files and built-ins: everything the renderer
//! would turn into NaNs, empty images or nonsense is refused with the part it concerns.
use super::error::object_label;
use super::{Animation, CameraSpec, Scene, SceneError, SceneObject, Settings, Shape};
use glam::Vec3;
use shared::types::{Material, MaterialKind};

/// Accepts `scene` or says, naming `file`, which value is out of range.
pub(super) fn check(scene: &Scene, file: &str) -> Result<(), SceneError> {
    let invalid = |what: String, problem: String| SceneError::Invalid {
        file: file.to_string(),
        what,
        problem,
    };
    camera(&scene.camera).map_err(|p| invalid("camera".into(), p))?;
    settings(&scene.settings).map_err(|p| invalid("render".into(), p))?;
    for (name, m) in &scene.materials {
        material(m).map_err(|p| invalid(format!("material \"{name}\""), p))?;
    }
    if scene.objects.is_empty() {
        return Err(SceneError::Empty { file: file.to_string() });
    }
    for (i, o) in scene.objects.iter().enumerate() {
        object(scene, o).map_err(|p| invalid(object_label(i, &o.name), p))?;
    }
    let (tris, spheres) = scene.counts();
    if tris + spheres > u32::MAX as usize / 2 {
        return Err(invalid(
            "scene".into(),
            format!("{tris} triangles and {spheres} spheres are too many"),
        ));
    }
    Ok(())
}

fn finite(what: &str, v: Vec3) -> Result<(), String> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(format!("{what} must be finite, got {v}"))
    }
}

fn positive(what: &str, x: f32) -> Result<(), String> {
    if x > 0.0 && x.is_finite() {
        Ok(())
    } else {
        Err(format!("{what} must be positive and finite, got {x}"))
    }
}

fn non_negative(what: &str, v: Vec3) -> Result<(), String> {
    if v.is_finite() && v.min_element() >= 0.0 {
        Ok(())
    } else {
        Err(format!("{what} must be finite and not negative, got {v}"))
    }
}

fn camera(c: &CameraSpec) -> Result<(), String> {
    finite("position", c.position)?;
    finite("look_at", c.look_at)?;
    finite("up", c.up)?;
    if !(c.vfov_deg > 0.0 && c.vfov_deg < 180.0) {
        return Err(format!(
            "vfov must lie strictly between 0 and 180 degrees, got {}",
            c.vfov_deg
        ));
    }
    if !(c.aperture >= 0.0 && c.aperture.is_finite()) {
        return Err(format!("aperture must be finite and not negative, got {}", c.aperture));
    }
    if let Some(f) = c.focus_distance {
        positive("focus_distance", f)?;
    }
    let view = c.look_at - c.position;
    if view.length() == 0.0 {
        return Err("position and look_at are the same point".into());
    }
    if c.up.cross(view).length() <= 1e-6 * c.up.length() * view.length() {
        return Err("up is parallel to the view direction (or zero)".into());
    }
    Ok(())
}

fn settings(s: &Settings) -> Result<(), String> {
    if s.width == 0 || s.height == 0 {
        return Err(format!(
            "width and height must be positive, got {}x{}",
            s.width, s.height
        ));
    }
    if s.spp == 0 {
        return Err("spp must be positive, got 0".into());
    }
    if s.max_depth == 0 {
        return Err("depth must be positive, got 0".into());
    }
    positive("exposure", s.exposure)?;
    non_negative("sky top", s.sky_top)?;
    non_negative("sky bottom", s.sky_bottom)
}

fn material(m: &Material) -> Result<(), String> {
    let xyz = |v: [f32; 4]| Vec3::new(v[0], v[1], v[2]);
    non_negative("albedo", xyz(m.albedo))?;
    non_negative("emission", xyz(m.emission))?;
    if m.kind > MaterialKind::Pbr as u32 {
        return Err(format!("kind {} is not a material kind", m.kind));
    }
    if !(0.0..=1.0).contains(&m.roughness) {
        return Err(format!("roughness must lie in [0, 1], got {}", m.roughness));
    }
    if m.kind == MaterialKind::Dielectric as u32 || m.kind == MaterialKind::Pbr as u32 {
        positive("ior", m.ior)?;
    }
    if !(0.0..=1.0).contains(&m.metallic) {
        return Err(format!("metallic must lie in [0, 1], got {}", m.metallic));
    }
    Ok(())
}

fn object(scene: &Scene, o: &SceneObject) -> Result<(), String> {
    let t = o.transform;
    finite("translation", t.translation)?;
    finite("rotation", t.rotation_deg)?;
    for s in t.scale.to_array() {
        positive("scale", s)?;
    }
    match o.shape {
        Shape::Mesh(m) if m >= scene.meshes.len() => return Err(format!("mesh index {m} does not exist")),
        Shape::Mesh(_) => {}
        Shape::Sphere { radius } => {
            positive("sphere radius", radius)?;
            if t.scale.max_element() - t.scale.min_element() > 1e-6 * t.scale.max_element() {
                return Err(format!("a sphere needs a uniform scale, got {}", t.scale));
            }
            if o.animation.wave.is_some() {
                return Err("a sphere cannot wave: waves deform a mesh's triangles".into());
            }
            if o.instance == Some(false) {
                return Err(
                    "instance = false is for meshes: a sphere of a two-level scene is always an instance".into(),
                );
            }
        }
    }
    if o.material as usize >= scene.materials.len() {
        return Err(format!("material index {} does not exist", o.material));
    }
    animation(&o.animation)
}

fn animation(a: &Animation) -> Result<(), String> {
    finite("spin", a.spin_deg_per_s)?;
    if let Some(o) = a.orbit {
        finite("orbit center", o.center)?;
        if !(o.radius >= 0.0 && o.radius.is_finite()) {
            return Err(format!(
                "orbit radius must be finite and not negative, got {}",
                o.radius
            ));
        }
        positive("orbit period", o.period_s)?;
    }
    if let Some(b) = a.bob {
        if !b.amplitude.is_finite() {
            return Err(format!("bob amplitude must be finite, got {}", b.amplitude));
        }
        positive("bob period", b.period_s)?;
    }
    if let Some(w) = a.wave {
        if !w.amplitude.is_finite() || !w.heading_deg.is_finite() {
            return Err(format!(
                "wave amplitude and heading must be finite, got {} and {}",
                w.amplitude, w.heading_deg
            ));
        }
        positive("wave length", w.wavelength)?;
        positive("wave period", w.period_s)?;
    }
    Ok(())
}
