//! Vertex attributes of meshes on the host: each triangle's [`VertexAttrs`] (shading normals
//! and texture coordinates of its three corners) from a file's per-vertex data, smooth
//! normals computed where a file has none, and attributes carried through a transform baked
//! into a mesh.
//!
//! Computed normals weight each face's normal by its area and its angle at the vertex (the
//! area- and angle-weighted average recommended by Jin, Lewis and West 2005, "A comparison
//! of algorithms for vertex normal computation"), and only faces within the crease angle of
//! the corner's own face count (a cube keeps its edges, a scanned surface comes out smooth).
//! Corners are joined by exact position, so a mesh whose vertices are split for UV seams
//! still shades smoothly across them.
use glam::{Mat3, Vec3};
use shared::types::{xyz, Triangle, VertexAttrs};
use std::collections::HashMap;

/// The crease angle used where a file has no normals and the scene asks for none.
pub const DEFAULT_CREASE_DEG: f32 = 60.0;

/// How a mesh's shading normals are chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Normals {
    /// The file's normals; where it has none: smooth at [`DEFAULT_CREASE_DEG`] for OBJ and
    /// PLY, flat for glTF (as its specification asks).
    Auto,
    /// The geometric normal of each triangle.
    Flat,
    /// Computed, joined across edges whose faces meet within this many degrees.
    Smooth { crease_deg: f32 },
}

/// Attributes from per-vertex data: `faces` index `normals` and `uvs` (either may be
/// missing: zeros). Non-finite values become zeros (the geometric normal shades there).
pub fn from_vertices(faces: &[[u32; 3]], normals: Option<&[[f32; 3]]>, uvs: Option<&[[f32; 2]]>) -> Vec<VertexAttrs> {
    let clean = |x: f32| if x.is_finite() { x } else { 0.0 };
    faces
        .iter()
        .map(|f| {
            let mut a = VertexAttrs::default();
            for (k, &i) in f.iter().enumerate() {
                let n = normals.and_then(|n| n.get(i as usize)).copied().unwrap_or_default();
                let n = if n.iter().all(|x| x.is_finite()) { n } else { [0.0; 3] };
                let uv = uvs.and_then(|u| u.get(i as usize)).copied().unwrap_or_default();
                a.normal_u[k] = [n[0], n[1], n[2], clean(uv[0])];
                a.v[k] = clean(uv[1]);
            }
            a
        })
        .collect()
}

/// `attrs` with smooth normals computed for `tris` (see the module header), keeping their
/// texture coordinates (`attrs` may be empty: none).
pub fn smooth(tris: &[Triangle], attrs: &[VertexAttrs], crease_deg: f32) -> Vec<VertexAttrs> {
    let corners = |t: &Triangle| [xyz(t.v0), xyz(t.v1), xyz(t.v2)];
    let key = |p: Vec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    let face_normal: Vec<Vec3> = tris
        .iter()
        .map(|t| {
            let [a, b, c] = corners(t);
            (b - a).cross(c - a).normalize_or_zero()
        })
        .collect();
    // Every face's contribution at each of its corners: unit normal times area times angle.
    let mut at_point: HashMap<[u32; 3], Vec<(usize, Vec3)>> = HashMap::new();
    for (f, t) in tris.iter().enumerate() {
        let p = corners(t);
        let area2 = (p[1] - p[0]).cross(p[2] - p[0]).length();
        for k in 0..3 {
            let (e1, e2) = (p[(k + 1) % 3] - p[k], p[(k + 2) % 3] - p[k]);
            let angle = e1.angle_between(e2);
            let weight = if angle.is_finite() { angle * area2 } else { 0.0 };
            at_point
                .entry(key(p[k]))
                .or_default()
                .push((f, face_normal[f] * weight));
        }
    }
    let cos_crease = crease_deg.to_radians().cos();
    tris.iter()
        .enumerate()
        .map(|(f, t)| {
            let mut a = attrs.get(f).copied().unwrap_or_default();
            for (k, p) in corners(t).into_iter().enumerate() {
                let n: Vec3 = at_point[&key(p)]
                    .iter()
                    .filter(|(g, _)| face_normal[*g].dot(face_normal[f]) >= cos_crease)
                    .map(|(_, n)| *n)
                    .sum();
                let n = n.normalize_or_zero();
                a.normal_u[k][..3].copy_from_slice(&n.to_array());
            }
            a
        })
        .collect()
}

/// `a` with its normals removed (texture coordinates kept).
pub fn without_normals(a: &VertexAttrs) -> VertexAttrs {
    let mut out = *a;
    for n in &mut out.normal_u {
        n[..3].copy_from_slice(&[0.0; 3]);
    }
    out
}

/// Whether any corner of `attrs` has a normal.
pub fn has_normals(attrs: &[VertexAttrs]) -> bool {
    attrs.iter().any(|a| a.normal_u.iter().any(|n| n[..3] != [0.0; 3]))
}

/// Whether any corner of `attrs` has non-zero texture coordinates.
pub fn has_uvs(attrs: &[VertexAttrs]) -> bool {
    attrs
        .iter()
        .any(|a| a.normal_u.iter().any(|n| n[3] != 0.0) || a.v[..3] != [0.0; 3])
}

/// `attrs` of triangles whose positions moved by the linear part `linear` of a matrix baked
/// into the mesh: normals by its inverse transpose (normalised), corners 1 and 2 swapped where
/// `mirrored` (the baked triangles swap them to keep their front side).
pub fn transformed(attrs: &[VertexAttrs], linear: Mat3, mirrored: bool) -> Vec<VertexAttrs> {
    // The cofactor is the inverse transpose times the determinant: its sign flips normals
    // with a mirror, as the edges' cross product flips; the swapped corners flip that back.
    let sign = if linear.determinant() < 0.0 { -1.0 } else { 1.0 };
    let normal_matrix = cofactor(linear) * sign;
    attrs
        .iter()
        .map(|a| {
            let mut out = *a;
            for k in 0..3 {
                let n = normal_matrix * xyz(a.normal_u[k]);
                let n = n.normalize_or_zero();
                out.normal_u[k][..3].copy_from_slice(&n.to_array());
            }
            if mirrored {
                out.normal_u.swap(1, 2);
                out.v.swap(1, 2);
            }
            out
        })
        .collect()
}

/// The cofactor matrix of `m` (its inverse transpose times its determinant): takes normals
/// through `m` on the side its transformed edges' cross products take, and is defined for
/// singular `m` too.
pub fn cofactor(m: Mat3) -> Mat3 {
    Mat3::from_cols(
        m.y_axis.cross(m.z_axis),
        m.z_axis.cross(m.x_axis),
        m.x_axis.cross(m.y_axis),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> Triangle {
        let v = |p: [f32; 3]| [p[0], p[1], p[2], 0.0];
        Triangle {
            v0: v(a),
            v1: v(b),
            v2: v(c),
        }
    }

    fn normal(a: &VertexAttrs, k: usize) -> Vec3 {
        xyz(a.normal_u[k])
    }

    #[test]
    fn a_fold_within_the_crease_angle_is_smoothed_and_a_cube_edge_is_not() {
        // Two faces meeting at the x axis, one flat (normal +z), one tilted by 30 degrees.
        let (s, c) = 30f32.to_radians().sin_cos();
        let flat = tri([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let tilted = tri([1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, -c, s]);
        let smooth45 = smooth(&[flat, tilted], &[], 45.0);
        // On the shared edge both faces see the same normal, halfway between theirs.
        let shared = normal(&smooth45[0], 0);
        assert!((shared - normal(&smooth45[1], 1)).length() < 1e-6);
        assert!(
            (shared.angle_between(Vec3::Z).to_degrees() - 15.0).abs() < 1.0,
            "{shared}"
        );
        // Off the edge each corner keeps its own face's normal.
        assert!((normal(&smooth45[0], 2) - Vec3::Z).length() < 1e-6);
        // A crease angle below the fold keeps the faces apart.
        let sharp = smooth(&[flat, tilted], &[], 20.0);
        assert!((normal(&sharp[0], 0) - Vec3::Z).length() < 1e-6);
    }

    #[test]
    fn larger_faces_weigh_more() {
        // A large flat face and a small tilted one share a corner at the origin.
        let big = tri([0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0]);
        let small = tri([0.0, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.0, -0.1, 0.1]);
        let n = normal(&smooth(&[big, small], &[], 90.0)[0], 0);
        assert!(n.angle_between(Vec3::Z).to_degrees() < 1.0, "{n}");
    }

    #[test]
    fn degenerate_faces_and_bad_file_values_give_no_normal() {
        let line = tri([0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        assert!(!has_normals(&smooth(&[line], &[], 60.0)));
        let a = from_vertices(
            &[[0, 1, 2]],
            Some(&[[f32::NAN, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0; 3]]),
            None,
        );
        assert_eq!(normal(&a[0], 0), Vec3::ZERO);
        assert_eq!(normal(&a[0], 1), Vec3::Z);
        assert!(!has_uvs(&a));
    }

    #[test]
    fn a_mirror_keeps_normals_on_the_front_side() {
        let t = tri([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let a = from_vertices(
            &[[0, 1, 2]],
            Some(&[[0.0, 0.0, 1.0]; 3]),
            Some(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
        );
        let mirror = Mat3::from_diagonal(Vec3::new(-1.0, 1.0, 1.0));
        let moved = transformed(&a, mirror, true);
        // The baked triangle (corners 1 and 2 swapped) faces the same way as its normals.
        let p = |v: [f32; 4]| mirror * xyz(v);
        let (a0, a1, a2) = (p(t.v0), p(t.v2), p(t.v1));
        let front = (a1 - a0).cross(a2 - a0).normalize();
        assert!(normal(&moved[0], 0).dot(front) > 0.99);
        assert_eq!((moved[0].normal_u[1][3], moved[0].v[1]), (0.0, 1.0));
        // A non-uniform scale bends normals the inverse-transpose way.
        let squash = Mat3::from_diagonal(Vec3::new(1.0, 2.0, 1.0));
        let n = transformed(
            &from_vertices(&[[0, 0, 0]], Some(&[[0.0, 1.0, 1.0]]), None),
            squash,
            false,
        );
        let want = Vec3::new(0.0, 0.5, 1.0).normalize();
        assert!((normal(&n[0], 0) - want).length() < 1e-6);
    }
}
