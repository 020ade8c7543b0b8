//! The viewer's fly camera: moves along its own axes, turns by yaw (about world up, +y) and
//! pitch, and hands the renderer a [`CameraSpec`]. Until it moves it gives back the scene's
//! camera unchanged, so a still viewer renders exactly what `raytrace render` renders.
use crate::scene::CameraSpec;
use glam::Vec3;

pub struct FlyCamera {
    spec: CameraSpec,
    home: CameraSpec,
    /// Radians about +y; 0 looks along -z.
    yaw: f32,
    /// Radians above the horizon, within ±89°.
    pitch: f32,
    /// World units per second.
    pub speed: f32,
}

const PITCH_LIMIT: f32 = 89.0 * std::f32::consts::PI / 180.0;

impl FlyCamera {
    pub fn new(spec: CameraSpec) -> FlyCamera {
        let d = (spec.look_at - spec.position).normalize_or(Vec3::NEG_Z);
        FlyCamera {
            spec,
            home: spec,
            yaw: d.x.atan2(-d.z),
            pitch: d.y.clamp(-1.0, 1.0).asin().clamp(-PITCH_LIMIT, PITCH_LIMIT),
            speed: 0.5 * (spec.look_at - spec.position).length().max(1e-3),
        }
    }

    /// The camera to render with.
    pub fn spec(&self) -> CameraSpec {
        self.spec
    }

    /// Unit vector the camera looks along.
    pub fn forward(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(sy * cp, sp, -cy * cp)
    }

    fn right(&self) -> Vec3 {
        self.forward().cross(Vec3::Y).normalize_or(Vec3::X)
    }

    fn focus(&self) -> f32 {
        (self.spec.look_at - self.spec.position).length().max(1e-3)
    }

    /// Moves by `amount` along (right, up, forward) in camera space.
    pub fn fly(&mut self, amount: Vec3) {
        if amount == Vec3::ZERO {
            return;
        }
        let d = self.right() * amount.x + Vec3::Y * amount.y + self.forward() * amount.z;
        self.spec.position += d;
        self.spec.look_at += d;
    }

    /// Turns by `yaw` and `pitch` radians.
    pub fn turn(&mut self, yaw: f32, pitch: f32) {
        if yaw == 0.0 && pitch == 0.0 {
            return;
        }
        let focus = self.focus();
        self.yaw += yaw;
        self.pitch = (self.pitch + pitch).clamp(-PITCH_LIMIT, PITCH_LIMIT);
        self.spec.up = Vec3::Y;
        self.spec.look_at = self.spec.position + self.forward() * focus;
    }

    /// Narrows (negative) or widens the vertical field of view by `degrees`, within 5..150°.
    pub fn zoom(&mut self, degrees: f32) {
        self.spec.vfov_deg = (self.spec.vfov_deg + degrees).clamp(5.0, 150.0);
    }

    /// Back to the scene's camera.
    pub fn reset(&mut self) {
        let speed = self.speed;
        *self = FlyCamera::new(self.home);
        self.speed = speed;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> CameraSpec {
        CameraSpec {
            position: Vec3::new(0.0, 1.0, 5.0),
            look_at: Vec3::new(0.0, 1.0, 0.0),
            up: Vec3::Y,
            vfov_deg: 40.0,
            aperture: 0.0,
            focus_distance: None,
        }
    }

    #[test]
    fn an_unmoved_camera_is_the_scene_camera() {
        assert_eq!(FlyCamera::new(spec()).spec(), spec());
    }

    #[test]
    fn flying_forward_moves_towards_the_target_and_reset_returns() {
        let mut c = FlyCamera::new(spec());
        assert!((c.forward() - Vec3::NEG_Z).length() < 1e-6);
        c.fly(Vec3::new(0.0, 0.0, 2.0));
        assert!((c.spec().position - Vec3::new(0.0, 1.0, 3.0)).length() < 1e-6);
        c.fly(Vec3::new(1.0, 0.0, 0.0));
        assert!(
            (c.spec().position - Vec3::new(1.0, 1.0, 3.0)).length() < 1e-6,
            "right is +x"
        );
        c.reset();
        assert_eq!(c.spec(), spec());
    }

    #[test]
    fn turning_keeps_the_focus_distance_and_clamps_pitch() {
        let mut c = FlyCamera::new(spec());
        c.turn(std::f32::consts::FRAC_PI_2, 0.0);
        let s = c.spec();
        assert!((s.look_at - Vec3::new(5.0, 1.0, 5.0)).length() < 1e-5, "{}", s.look_at);
        c.turn(0.0, 10.0);
        let d = (c.spec().look_at - c.spec().position).normalize();
        assert!(d.y < 1.0 && d.y > 0.99, "pitch clamped below 90°: {d}");
        c.zoom(-100.0);
        assert_eq!(c.spec().vfov_deg, 5.0);
    }
}
