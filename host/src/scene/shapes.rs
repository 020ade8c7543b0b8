//! Meshes that need no file (`mesh = "builtin:NAME"` in scene files): a unit quad, the quad
//! cut into a 64 by 64 grid (a surface to wave) and a unit cube, wound so that
//! `cross(v1 - v0, v2 - v0)` points out of the surface.
use super::Transform;
use glam::Vec3;
use shared::types::Triangle;

/// Names accepted after `builtin:`.
pub const NAMES: [&str; 3] = ["cube", "grid", "quad"];

/// The mesh called `name` (without the `builtin:` prefix), if there is one.
pub fn by_name(name: &str) -> Option<Vec<Triangle>> {
    match name {
        "cube" => Some(cube()),
        "quad" => Some(quad()),
        "grid" => Some(grid(64, 64)),
        _ => None,
    }
}

fn corner(p: Vec3) -> [f32; 4] {
    [p.x, p.y, p.z, 0.0]
}

/// The unit square `[-0.5, 0.5]` in x and z at `y = 0`, facing `+y`: 2 triangles.
pub fn quad() -> Vec<Triangle> {
    let [a, b, c, d] = [(-0.5, -0.5), (-0.5, 0.5), (0.5, 0.5), (0.5, -0.5)].map(|(x, z)| corner(Vec3::new(x, 0.0, z)));
    vec![Triangle { v0: a, v1: b, v2: c }, Triangle { v0: a, v1: c, v2: d }]
}

/// The unit square of [`quad`] cut into `nx` by `nz` cells: `2 nx nz` triangles (a surface
/// to deform: a wave needs vertices to move).
pub fn grid(nx: u32, nz: u32) -> Vec<Triangle> {
    let at = |i: u32, j: u32| corner(Vec3::new(i as f32 / nx as f32 - 0.5, 0.0, j as f32 / nz as f32 - 0.5));
    let mut tris = Vec::with_capacity(2 * (nx * nz) as usize);
    for j in 0..nz {
        for i in 0..nx {
            let [a, b, c, d] = [at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j)];
            tris.push(Triangle { v0: a, v1: b, v2: c });
            tris.push(Triangle { v0: a, v1: c, v2: d });
        }
    }
    tris
}

/// The unit cube `[-0.5, 0.5]^3`, faces outward: 12 triangles.
pub fn cube() -> Vec<Triangle> {
    // The quad moved onto each face: (rotation in degrees, face centre).
    let faces = [
        (Vec3::ZERO, Vec3::Y),
        (Vec3::new(180.0, 0.0, 0.0), -Vec3::Y),
        (Vec3::new(0.0, 0.0, -90.0), Vec3::X),
        (Vec3::new(0.0, 0.0, 90.0), -Vec3::X),
        (Vec3::new(90.0, 0.0, 0.0), Vec3::Z),
        (Vec3::new(-90.0, 0.0, 0.0), -Vec3::Z),
    ];
    let mut tris = Vec::with_capacity(12);
    for (rotation, normal) in faces {
        let m = Transform::new(normal * 0.5, rotation, Vec3::ONE).matrix();
        let moved = |v: [f32; 4]| corner(m.transform_point3(Vec3::new(v[0], v[1], v[2])));
        tris.extend(quad().into_iter().map(|t| Triangle {
            v0: moved(t.v0),
            v1: moved(t.v1),
            v2: moved(t.v2),
        }));
    }
    tris
}

#[cfg(test)]
mod tests {
    use super::*;

    fn xyz(v: [f32; 4]) -> Vec3 {
        Vec3::new(v[0], v[1], v[2])
    }

    fn normal(t: &Triangle) -> Vec3 {
        (xyz(t.v1) - xyz(t.v0)).cross(xyz(t.v2) - xyz(t.v0)).normalize()
    }

    #[test]
    fn quad_lies_at_y0_facing_up() {
        let q = quad();
        assert_eq!(q.len(), 2);
        for t in &q {
            assert!((normal(t) - Vec3::Y).length() < 1e-6);
            assert!([t.v0, t.v1, t.v2]
                .iter()
                .all(|v| v[1] == 0.0 && v[0].abs() == 0.5 && v[2].abs() == 0.5));
        }
    }

    #[test]
    fn cube_faces_point_outward() {
        let c = cube();
        assert_eq!(c.len(), 12);
        for t in &c {
            let centre = (xyz(t.v0) + xyz(t.v1) + xyz(t.v2)) / 3.0;
            let n = normal(t);
            // Each face's normal is the axis its centre lies on.
            assert!(n.dot(centre) > 0.49, "{t:?}");
            for v in [t.v0, t.v1, t.v2] {
                assert!(xyz(v).abs().max_element() - 0.5 < 1e-6, "{v:?}");
            }
        }
        let area: f32 = c
            .iter()
            .map(|t| 0.5 * (xyz(t.v1) - xyz(t.v0)).cross(xyz(t.v2) - xyz(t.v0)).length())
            .sum();
        assert!((area - 6.0).abs() < 1e-5);
    }
}
