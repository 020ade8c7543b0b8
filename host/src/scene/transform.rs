//! Object placement: a translation, Tait-Bryan rotation and scale ([`Transform`]), and the
//! animations ([`Animation`]) that move it over time.
use glam::{Affine3A, EulerRot, Quat, Vec3};
use std::f32::consts::TAU;

/// Places an object in the world: scale, then rotate, then translate.
///
/// The rotation is given as Tait-Bryan angles in degrees about x, y and z, applied as in the
/// thesis: the model-to-world matrix is `T * Ry * Rx * Rz * S`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    pub translation: Vec3,
    /// Angles in degrees about the x, y and z axes.
    pub rotation_deg: Vec3,
    pub scale: Vec3,
}

impl Transform {
    /// No translation, no rotation, unit scale.
    pub const IDENTITY: Transform = Transform {
        translation: Vec3::ZERO,
        rotation_deg: Vec3::ZERO,
        scale: Vec3::ONE,
    };

    /// A transform from its three parts.
    pub fn new(translation: Vec3, rotation_deg: Vec3, scale: Vec3) -> Transform {
        Transform {
            translation,
            rotation_deg,
            scale,
        }
    }

    /// A translation alone.
    pub fn at(translation: Vec3) -> Transform {
        Transform {
            translation,
            ..Transform::IDENTITY
        }
    }

    /// The rotation alone: `Ry * Rx * Rz`.
    pub fn rotation(&self) -> Quat {
        let r = self.rotation_deg;
        Quat::from_euler(EulerRot::YXZ, r.y.to_radians(), r.x.to_radians(), r.z.to_radians())
    }

    /// The model-to-world matrix `T * Ry * Rx * Rz * S`.
    pub fn matrix(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(self.scale, self.rotation(), self.translation)
    }
}

impl Default for Transform {
    fn default() -> Transform {
        Transform::IDENTITY
    }
}

/// Motion of an object over time, applied to its base transform by [`Animation::apply`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Animation {
    /// Added to the rotation angles, in degrees per second about x, y and z.
    pub spin_deg_per_s: Vec3,
    /// A circle in the xz plane; replaces the base translation.
    pub orbit: Option<Orbit>,
    /// A sinusoidal offset along y, added last.
    pub bob: Option<Bob>,
    /// Waves running over the object's triangles: its shape changes every frame (the
    /// transform stage deforms it: `shared::transform::waved`).
    pub wave: Option<Wave>,
}

/// Waves along y over a mesh's model space: crests `wavelength` apart running towards
/// `heading_deg` (about y; 0: towards +x), one wavelength every `period_s`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wave {
    pub amplitude: f32,
    pub wavelength: f32,
    pub period_s: f32,
    pub heading_deg: f32,
}

impl Wave {
    /// `Object::wave` at `time_s`: amplitude, waves per unit along x and z, phase in waves
    /// (its fraction: large times keep their precision).
    pub fn params(&self, time_s: f32) -> [f32; 4] {
        let (s, c) = self.heading_deg.to_radians().sin_cos();
        let phase = (time_s as f64 / self.period_s as f64).rem_euclid(1.0) as f32;
        [self.amplitude, c / self.wavelength, s / self.wavelength, phase]
    }
}

/// A circular path in the xz plane: at time `t` the object is at
/// `center + radius * (cos φ, 0, sin φ)` with `φ = 2π t / period_s`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    pub center: Vec3,
    pub radius: f32,
    pub period_s: f32,
}

/// An up-and-down motion: `amplitude * sin(2π t / period_s)` added to the y translation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bob {
    pub amplitude: f32,
    pub period_s: f32,
}

impl Animation {
    /// `base` moved to where this animation has it at `time_s` seconds.
    pub fn apply(&self, base: Transform, time_s: f32) -> Transform {
        let mut t = base;
        t.rotation_deg += self.spin_deg_per_s * time_s;
        if let Some(o) = self.orbit {
            let phi = TAU * time_s / o.period_s;
            t.translation = o.center + o.radius * Vec3::new(phi.cos(), 0.0, phi.sin());
        }
        if let Some(b) = self.bob {
            t.translation.y += b.amplitude * (TAU * time_s / b.period_s).sin();
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Vec4};

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).abs().max_element() < 1e-5
    }

    #[test]
    fn rotating_z_by_90_about_y_gives_x() {
        let t = Transform::new(Vec3::ZERO, Vec3::new(0.0, 90.0, 0.0), Vec3::ONE);
        let p = t.matrix().transform_point3(Vec3::Z);
        assert!(close(p, Vec3::X), "{p}");
    }

    #[test]
    fn rotation_order_is_y_then_x_then_z() {
        let t = Transform::new(
            Vec3::new(1.0, -2.0, 3.0),
            Vec3::new(30.0, 45.0, 60.0),
            Vec3::new(2.0, 3.0, 4.0),
        );
        let expected = Mat4::from_translation(t.translation)
            * Mat4::from_rotation_y(45f32.to_radians())
            * Mat4::from_rotation_x(30f32.to_radians())
            * Mat4::from_rotation_z(60f32.to_radians())
            * Mat4::from_scale(t.scale);
        let m = t.matrix();
        for p in [Vec3::X, Vec3::Y, Vec3::Z, Vec3::new(0.3, -1.7, 2.5)] {
            let want = (expected * Vec4::from((p, 1.0))).truncate();
            assert!(
                close(m.transform_point3(p), want),
                "{p}: {} != {want}",
                m.transform_point3(p)
            );
        }
        // A different order gives a different matrix, so the check above means something.
        let zxy = Mat4::from_translation(t.translation)
            * Mat4::from_rotation_z(60f32.to_radians())
            * Mat4::from_rotation_x(30f32.to_radians())
            * Mat4::from_rotation_y(45f32.to_radians())
            * Mat4::from_scale(t.scale);
        assert!(!close(
            m.transform_point3(Vec3::X),
            (zxy * Vec4::new(1.0, 0.0, 0.0, 1.0)).truncate()
        ));
    }

    #[test]
    fn animation_moves_the_transform_over_time() {
        let base = Transform::new(Vec3::new(5.0, 1.0, 5.0), Vec3::new(0.0, 10.0, 0.0), Vec3::ONE);
        let spin = Animation {
            spin_deg_per_s: Vec3::new(0.0, 30.0, 0.0),
            ..Default::default()
        };
        assert_eq!(spin.apply(base, 0.0), base);
        assert_eq!(spin.apply(base, 2.0).rotation_deg, Vec3::new(0.0, 70.0, 0.0));

        let orbit = Animation {
            orbit: Some(Orbit {
                center: Vec3::new(1.0, 2.0, 3.0),
                radius: 4.0,
                period_s: 8.0,
            }),
            ..Default::default()
        };
        assert!(close(orbit.apply(base, 0.0).translation, Vec3::new(5.0, 2.0, 3.0)));
        assert!(close(orbit.apply(base, 2.0).translation, Vec3::new(1.0, 2.0, 7.0)));

        let bob = Animation {
            bob: Some(Bob {
                amplitude: 0.5,
                period_s: 4.0,
            }),
            ..Default::default()
        };
        assert!(close(bob.apply(base, 1.0).translation, Vec3::new(5.0, 1.5, 5.0)));
        assert!(close(bob.apply(base, 3.0).translation, Vec3::new(5.0, 0.5, 5.0)));
        assert_eq!(Animation::default().apply(base, 123.0), base);
    }
}
