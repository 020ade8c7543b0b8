//! The built-in scenes ([`Scene::BUILTINS`]): the Cornell box with its two blocks, the box
//! holding Suzanne or the Stanford bunny, Ray Tracing in One Weekend's final scene of spheres,
//! a 4x4 grid of spinning bunnies of over a million triangles, a 12x12 herd of ten million,
//! and a forest of 24,386 objects and 1.23 billion triangles (instanced, its pond waving).
//! Walls and blocks are objects made of the built-in quad and cube, so they can be moved like
//! any other.
use super::{
    material, shapes, validate, Animation, Bob, CameraSpec, Mesh, Scene, SceneError, SceneObject, Settings, Shape,
    Transform, Wave,
};
use crate::inputs;
use glam::{Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use shared::types::{Material, Triangle};

/// The built-in scene `name`, checked like a scene file.
pub(super) fn build(name: &str) -> Result<Scene, SceneError> {
    let label = format!("built-in scene {name}");
    let scene = match name {
        "cornell" => cornell(),
        "suzanne" => cornell_holding(&label, "suzanne.obj", 180.0)?,
        "bunny" => cornell_holding(&label, "bunny.obj", -60.0)?,
        "spheres" => spheres(),
        "instances" => instances(&label)?,
        "herd" => herd(&label)?,
        "forest" => forest(&label)?,
        _ => return Err(SceneError::UnknownBuiltin { name: name.to_string() }),
    };
    validate::check(&scene, &label)?;
    Ok(scene)
}

/// Adds materials, meshes and objects to a scene, handing out their indices.
struct Builder {
    scene: Scene,
}

impl Builder {
    fn new(name: &str, camera: CameraSpec, settings: Settings) -> Builder {
        Builder {
            scene: Scene {
                name: name.to_string(),
                punctual: Vec::new(),
                environment: None,
                textures: Default::default(),
                camera,
                settings,
                materials: Vec::new(),
                meshes: Vec::new(),
                objects: Vec::new(),
            },
        }
    }

    fn material(&mut self, name: &str, m: Material) -> u32 {
        self.scene.materials.push((name.to_string(), m));
        self.scene.materials.len() as u32 - 1
    }

    fn mesh(&mut self, name: &str, tris: Vec<Triangle>) -> usize {
        self.scene.meshes.push(Mesh::flat(name, tris));
        self.scene.meshes.len() - 1
    }

    fn object(&mut self, name: &str, shape: Shape, transform: Transform, material: u32) -> &mut SceneObject {
        self.scene.objects.push(SceneObject {
            name: name.to_string(),
            shape,
            transform,
            material,
            animation: Animation::default(),
            instance: None,
        });
        let last = self.scene.objects.len() - 1;
        &mut self.scene.objects[last]
    }
}

/// Loads `file` from the assets folder, naming `label` and the object in errors.
fn asset(label: &str, file: &str) -> Result<Vec<Triangle>, SceneError> {
    let path = inputs::assets_dir().join(file);
    inputs::load_obj(&path).map_err(|e| SceneError::Mesh {
        file: label.to_string(),
        object: file.to_string(),
        mesh: path.display().to_string(),
        message: format!("{e:#}"),
    })
}

/// Turns `tris` by `yaw_deg` about y and scales its largest extent to `size`, standing on
/// `base` (the centre of its lowest side).
fn stand(tris: &[Triangle], yaw_deg: f32, size: f32, base: Vec3) -> Transform {
    let rotation = Vec3::new(0.0, yaw_deg, 0.0);
    let turn = Transform::new(Vec3::ZERO, rotation, Vec3::ONE).matrix();
    let mut lo = Vec3::INFINITY;
    let mut hi = Vec3::NEG_INFINITY;
    for v in tris.iter().flat_map(|t| [t.v0, t.v1, t.v2]) {
        let p = turn.transform_point3(Vec3::new(v[0], v[1], v[2]));
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let scale = size / (hi - lo).max_element();
    let bottom = Vec3::new((lo.x + hi.x) / 2.0, lo.y, (lo.z + hi.z) / 2.0);
    Transform::new(base - scale * bottom, rotation, Vec3::splat(scale))
}

/// Side of the Cornell box.
const BOX: f32 = 555.0;

/// The Cornell box's camera, walls and ceiling light; returns the builder and the white material.
fn cornell_box(name: &str) -> (Builder, u32) {
    let camera = CameraSpec {
        position: Vec3::new(278.0, 278.0, -800.0),
        look_at: Vec3::new(278.0, 278.0, 0.0),
        up: Vec3::Y,
        vfov_deg: 40.0,
        aperture: 0.0,
        focus_distance: None,
    };
    let mut b = Builder::new(name, camera, Settings::default());
    let white = b.material("white", material::diffuse([0.73, 0.73, 0.73]));
    let green = b.material("green", material::diffuse([0.12, 0.45, 0.15]));
    let red = b.material("red", material::diffuse([0.65, 0.05, 0.05]));
    let light = b.material("light", material::emissive([15.0, 15.0, 15.0]));
    let quad = Shape::Mesh(b.mesh("builtin:quad", shapes::quad()));
    let half = BOX / 2.0;
    let wall = Vec3::new(BOX, 1.0, BOX);
    // The quad faces +y; each wall is turned to face into the box.
    let v = Vec3::new;
    let walls = [
        ("floor", v(half, 0.0, half), Vec3::ZERO, white),
        ("ceiling", v(half, BOX, half), v(180.0, 0.0, 0.0), white),
        ("back wall", v(half, half, BOX), v(-90.0, 0.0, 0.0), white),
        ("left wall", v(BOX, half, half), v(0.0, 0.0, 90.0), green),
        ("right wall", v(0.0, half, half), v(0.0, 0.0, -90.0), red),
    ];
    for (name, at, rotation, m) in walls {
        b.object(name, quad, Transform::new(at, rotation, wall), m);
    }
    let lamp = Transform::new(v(278.0, 554.0, 279.5), v(180.0, 0.0, 0.0), v(130.0, 1.0, 105.0));
    b.object("light", quad, lamp, light);
    (b, white)
}

/// The Cornell box of Ray Tracing: The Next Week with its tall and short block.
fn cornell() -> Scene {
    let (mut b, white) = cornell_box("cornell");
    let cube = Shape::Mesh(b.mesh("builtin:cube", shapes::cube()));
    // As in the book: a box with a corner at the origin, turned about y, then moved.
    let v = Vec3::new;
    let blocks = [
        ("tall block", v(165.0, 330.0, 165.0), 15.0, v(265.0, 0.0, 295.0)),
        ("short block", v(165.0, 165.0, 165.0), -18.0, v(130.0, 0.0, 65.0)),
    ];
    for (name, size, yaw, corner) in blocks {
        let centre = corner + Quat::from_rotation_y(f32::to_radians(yaw)) * (size / 2.0);
        let place = Transform::new(centre, v(0.0, yaw, 0.0), size);
        b.object(name, cube, place, white);
    }
    b.scene
}

/// The Cornell box without blocks, holding asset `file` turned by `yaw_deg` to face the camera.
fn cornell_holding(label: &str, file: &str, yaw_deg: f32) -> Result<Scene, SceneError> {
    let name = file.trim_end_matches(".obj");
    let (mut b, white) = cornell_box(name);
    let tris = asset(label, file)?;
    let place = stand(&tris, yaw_deg, 300.0, Vec3::new(BOX / 2.0, 0.0, BOX / 2.0));
    let mesh = Shape::Mesh(b.mesh(file, tris));
    b.object(name, mesh, place, white);
    Ok(b.scene)
}

/// Settings of the outdoor scenes: 1200 x 800 under a blue-to-white sky.
fn outdoor() -> Settings {
    Settings {
        width: 1200,
        height: 800,
        sky_top: Vec3::new(0.5, 0.7, 1.0),
        sky_bottom: Vec3::ONE,
        ..Settings::default()
    }
}

/// Ray Tracing in One Weekend's final scene, plus a light for next-event estimation.
fn spheres() -> Scene {
    let camera = CameraSpec {
        position: Vec3::new(13.0, 2.0, 3.0),
        look_at: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 20.0,
        aperture: 0.1,
        focus_distance: Some(10.0),
    };
    let settings = outdoor();
    let mut b = Builder::new("spheres", camera, settings);
    let sphere = |b: &mut Builder, name: &str, at: Vec3, radius: f32, m: u32| {
        b.object(name, Shape::Sphere { radius }, Transform::at(at), m);
    };
    let ground = b.material("ground", material::diffuse([0.5, 0.5, 0.5]));
    let glass = b.material("glass", material::dielectric(1.5));
    sphere(&mut b, "ground", Vec3::new(0.0, -1000.0, 0.0), 1000.0, ground);
    let mut rng = Pcg64::seed_from_u64(1);
    for a in -11..11 {
        for c in -11..11 {
            let choice: f32 = rng.random();
            let (dx, dz): (f32, f32) = (rng.random(), rng.random());
            let at = Vec3::new(a as f32 + 0.9 * dx, 0.2, c as f32 + 0.9 * dz);
            if (at - Vec3::new(4.0, 0.2, 0.0)).length() <= 0.9 {
                continue;
            }
            let name = format!("small {a} {c}");
            let m = if choice < 0.8 {
                let albedo: [f32; 3] = std::array::from_fn(|_| rng.random::<f32>() * rng.random::<f32>());
                b.material(&name, material::diffuse(albedo))
            } else if choice < 0.95 {
                let albedo: [f32; 3] = std::array::from_fn(|_| rng.random_range(0.5..1.0));
                b.material(&name, material::metal(albedo, rng.random_range(0.0..0.5)))
            } else {
                glass
            };
            sphere(&mut b, &name, at, 0.2, m);
        }
    }
    sphere(&mut b, "glass", Vec3::new(0.0, 1.0, 0.0), 1.0, glass);
    let brown = b.material("brown", material::diffuse([0.4, 0.2, 0.1]));
    sphere(&mut b, "diffuse", Vec3::new(-4.0, 1.0, 0.0), 1.0, brown);
    let bronze = b.material("bronze", material::metal([0.7, 0.6, 0.5], 0.0));
    sphere(&mut b, "metal", Vec3::new(4.0, 1.0, 0.0), 1.0, bronze);
    let light = b.material("light", material::emissive([6.0, 6.0, 6.0]));
    sphere(&mut b, "light", Vec3::new(0.0, 8.0, 3.0), 2.0, light);
    b.scene
}

/// The real-time scenes' field: eight looks (diffuse, metal, glass), a ground quad of `size`
/// on a side, and the Stanford bunny; returns the looks, the bunny's shape, its standing
/// placement and the light's material.
fn bunny_field(b: &mut Builder, label: &str, size: f32) -> Result<([u32; 8], Shape, Transform, u32), SceneError> {
    let looks = [
        b.material("red", material::diffuse([0.8, 0.2, 0.2])),
        b.material("gold", material::metal([0.9, 0.7, 0.3], 0.1)),
        b.material("green", material::diffuse([0.2, 0.7, 0.3])),
        b.material("glass", material::dielectric(1.5)),
        b.material("blue", material::diffuse([0.2, 0.3, 0.8])),
        b.material("steel", material::metal([0.8, 0.8, 0.85], 0.3)),
        b.material("white", material::diffuse([0.8, 0.8, 0.8])),
        b.material("copper", material::metal([0.95, 0.6, 0.4], 0.0)),
    ];
    let ground = b.material("ground", material::diffuse([0.5, 0.5, 0.5]));
    let light = b.material("light", material::emissive([10.0, 10.0, 10.0]));
    let quad = Shape::Mesh(b.mesh("builtin:quad", shapes::quad()));
    let floor = Transform::new(Vec3::ZERO, Vec3::ZERO, Vec3::new(size, 1.0, size));
    b.object("ground", quad, floor, ground);
    let tris = asset(label, "bunny.obj")?;
    let place = stand(&tris, -90.0, 2.4, Vec3::ZERO);
    let bunny = Shape::Mesh(b.mesh("bunny.obj", tris));
    Ok((looks, bunny, place, light))
}

/// Sixteen spinning Stanford bunnies in mixed materials on a ground quad, under a sky and a light.
fn instances(label: &str) -> Result<Scene, SceneError> {
    let camera = CameraSpec {
        position: Vec3::new(0.0, 10.0, -15.0),
        look_at: Vec3::new(0.0, 0.8, 0.5),
        up: Vec3::Y,
        vfov_deg: 40.0,
        aperture: 0.0,
        focus_distance: None,
    };
    let mut b = Builder::new("instances", camera, outdoor());
    let (looks, bunny, mut place, light) = bunny_field(&mut b, label, 100.0)?;
    let spacing = 3.0;
    for k in 0..16 {
        let (i, j) = ((k % 4) as f32, (k / 4) as f32);
        place.translation.x = (i - 1.5) * spacing;
        place.translation.z = (j - 1.5) * spacing;
        let direction = if k % 2 == 0 { 1.0 } else { -1.0 };
        let o = b.object(&format!("bunny {k}"), bunny, place, looks[k % looks.len()]);
        o.animation.spin_deg_per_s = Vec3::new(0.0, direction * (10.0 + 5.0 * k as f32), 0.0);
    }
    b.object(
        "light",
        Shape::Sphere { radius: 2.0 },
        Transform::at(Vec3::new(-6.0, 12.0, -6.0)),
        light,
    );
    Ok(b.scene)
}

/// A 12x12 herd of Stanford bunnies, 10,031,904 triangles in seven of the looks: every bunny
/// spins, every third also bobs (the real-time scene of ten million animated triangles).
fn herd(label: &str) -> Result<Scene, SceneError> {
    let camera = CameraSpec {
        position: Vec3::new(0.0, 22.0, -34.0),
        look_at: Vec3::new(0.0, 0.0, 2.0),
        up: Vec3::Y,
        vfov_deg: 40.0,
        aperture: 0.0,
        focus_distance: None,
    };
    let mut b = Builder::new("herd", camera, outdoor());
    let (looks, bunny, mut place, light) = bunny_field(&mut b, label, 200.0)?;
    let spacing = 3.0;
    for k in 0..144 {
        let (i, j) = ((k % 12) as f32, (k / 12) as f32);
        place.translation.x = (i - 5.5) * spacing;
        place.translation.z = (j - 5.5) * spacing;
        let direction = if k % 2 == 0 { 1.0 } else { -1.0 };
        let o = b.object(&format!("bunny {k}"), bunny, place, looks[k % 7]);
        o.animation.spin_deg_per_s = Vec3::new(0.0, direction * (10.0 + (k % 9) as f32 * 5.0), 0.0);
        if k % 3 == 0 {
            o.animation.bob = Some(Bob {
                amplitude: 0.5,
                period_s: 2.0 + (k % 5) as f32 * 0.5,
            });
        }
    }
    b.object(
        "light",
        Shape::Sphere { radius: 4.0 },
        Transform::at(Vec3::new(-12.0, 25.0, -12.0)),
        light,
    );
    Ok(b.scene)
}

/// A canopy: an icosphere of unit radius subdivided `levels` times (20 * 4^levels
/// triangles, counter-clockwise seen from outside), its vertices pushed in and out by a few
/// fixed waves so that it reads as foliage rather than a ball.
fn canopy(levels: u32) -> Vec<Triangle> {
    let mut ball = inputs::hard_cases::icosphere(levels);
    for p in &mut ball.verts {
        let w = (7.0 * p.x).sin() * (5.0 * p.y).cos() + (9.0 * p.z + 2.0 * p.x).sin() * 0.6 + (13.0 * p.y).sin() * 0.3;
        *p *= 1.0 + 0.08 * w;
    }
    ball.triangles(Vec3::ZERO)
}

/// A closed cylinder of unit radius from y = 0 to y = 1, `sides` sides (4 * sides triangles,
/// facing out).
fn trunk(sides: u32) -> Vec<Triangle> {
    let ring = |k: u32, y: f32| {
        let a = std::f32::consts::TAU * k as f32 / sides as f32;
        [a.cos(), y, a.sin(), 0.0]
    };
    let (bottom, top) = ([0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]);
    (0..sides)
        .flat_map(|k| {
            let (a0, a1, b0, b1) = (ring(k, 0.0), ring(k + 1, 0.0), ring(k, 1.0), ring(k + 1, 1.0));
            [
                Triangle { v0: a0, v1: b1, v2: a1 },
                Triangle { v0: a0, v1: b0, v2: b1 },
                Triangle {
                    v0: bottom,
                    v1: a0,
                    v2: a1,
                },
                Triangle {
                    v0: top,
                    v1: b1,
                    v2: b0,
                },
            ]
        })
        .collect()
}

/// A forest of 16,384 cells, 128 on a side: every other cell a tree (a trunk and a canopy of
/// 81,920 triangles: two instances), the rest Stanford bunnies in the real-time looks, an
/// eighth of them spinning and some bobbing, and a pond of 30,720 triangles in a clearing
/// whose surface waves (deformed every frame, its BVH built or refit: the world-space group); 24,386
/// objects and 1.23 billion triangles, 182,437 distinct. Rendered through two levels;
/// flattened it would need hundreds of gigabytes.
fn forest(label: &str) -> Result<Scene, SceneError> {
    let camera = CameraSpec {
        position: Vec3::new(0.0, 45.0, -215.0),
        look_at: Vec3::new(0.0, 0.0, -60.0),
        up: Vec3::Y,
        vfov_deg: 50.0,
        aperture: 0.0,
        focus_distance: None,
    };
    let mut b = Builder::new("forest", camera, outdoor());
    let (looks, bunny, place, light) = bunny_field(&mut b, label, 420.0)?;
    let bark = b.material("bark", material::diffuse([0.30, 0.20, 0.12]));
    let leaves = [
        b.material("leaves", material::diffuse([0.16, 0.42, 0.12])),
        b.material("dark leaves", material::diffuse([0.08, 0.28, 0.10])),
        b.material("autumn leaves", material::diffuse([0.62, 0.36, 0.08])),
    ];
    let canopy = Shape::Mesh(b.mesh("builtin:canopy", canopy(6)));
    let trunk = Shape::Mesh(b.mesh("builtin:trunk", trunk(32)));
    // A pond in front of the camera, waving: its triangles move every frame, so it is
    // transformed every frame, its BVH built or refit (the world-space group of the two levels).
    let water = b.material("water", material::metal([0.40, 0.55, 0.62], 0.05));
    let (pond_at, pond_size) = (Vec3::new(0.0, 0.05, -140.0), Vec3::new(40.0, 1.0, 24.0));
    let scaled = |v: [f32; 4]| [v[0] * pond_size.x, v[1], v[2] * pond_size.z, v[3]];
    let surface = shapes::grid(160, 96)
        .into_iter()
        .map(|t| Triangle {
            v0: scaled(t.v0),
            v1: scaled(t.v1),
            v2: scaled(t.v2),
        })
        .collect();
    let pond = Shape::Mesh(b.mesh("builtin:pond", surface));
    let o = b.object("pond", pond, Transform::at(pond_at), water);
    o.animation.wave = Some(Wave {
        amplitude: 0.25,
        wavelength: 6.0,
        period_s: 2.5,
        heading_deg: 30.0,
    });
    let (side, spacing) = (128, 3.0);
    let mut rng = Pcg64::seed_from_u64(7);
    for k in 0..side * side {
        let (i, j) = (k % side, k / side);
        let jitter = Vec3::new(rng.random_range(-0.6..0.6), 0.0, rng.random_range(-0.6..0.6));
        let at = Vec3::new((i as f32 - 63.5) * spacing, 0.0, (j as f32 - 63.5) * spacing) + jitter;
        let yaw: f32 = rng.random_range(0.0..360.0);
        let size: f32 = rng.random_range(0.8..1.3);
        if ((at - pond_at).abs() - pond_size / 2.0).max_element() < 2.0 {
            continue;
        }
        if (i + j) % 2 == 0 {
            let height = 1.6 * size;
            let stem = Transform::new(
                at,
                Vec3::new(0.0, yaw, 0.0),
                Vec3::new(0.12 * size, height, 0.12 * size),
            );
            b.object(&format!("trunk {k}"), trunk, stem, bark);
            let crown = Transform::new(
                at + Vec3::new(0.0, height + 0.9 * size, 0.0),
                Vec3::new(0.0, yaw, 0.0),
                Vec3::splat(1.1 * size),
            );
            let green = leaves[rng.random_range(0..leaves.len())];
            b.object(&format!("canopy {k}"), canopy, crown, green);
        } else {
            let mut t = place;
            t.translation += at;
            t.rotation_deg.y += yaw;
            let o = b.object(&format!("bunny {k}"), bunny, t, looks[k % 8]);
            if k % 16 == 1 {
                let direction = if k % 32 == 1 { 1.0 } else { -1.0 };
                o.animation.spin_deg_per_s = Vec3::new(0.0, direction * 40.0, 0.0);
            }
            if k % 48 == 3 {
                o.animation.bob = Some(Bob {
                    amplitude: 0.5,
                    period_s: 2.0,
                });
            }
        }
    }
    b.object(
        "light",
        Shape::Sphere { radius: 12.0 },
        Transform::at(Vec3::new(-60.0, 90.0, -160.0)),
        light,
    );
    Ok(b.scene)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::InstancingMode;

    fn world(o: &shared::types::Object, v: [f32; 4]) -> Vec3 {
        let r = o.rows;
        Vec3::new(
            r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2] + r[0][3],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2] + r[1][3],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2] + r[2][3],
        )
    }

    #[test]
    fn every_builtin_builds_consistent_gpu_data() {
        for name in Scene::BUILTINS {
            let scene = Scene::builtin(name).unwrap_or_else(|e| panic!("{e}"));
            // As the renderer lays it out by default: the forest is instanced.
            let gpu = scene.gpu_data_as(0.5, InstancingMode::Auto).unwrap();
            let (tris, spheres) = match &gpu.instancing {
                None => scene.counts(),
                Some(i) => i
                    .meshes
                    .iter()
                    .fold((0, 0), |(t, s), m| (t + m.tris.len(), s + m.spheres.len())),
            };
            assert_eq!(gpu.model_tris.len(), tris, "{name}");
            assert_eq!(gpu.model_spheres.len(), spheres, "{name}");
            assert_eq!(gpu.prim_object.len(), tris + spheres, "{name}");
            assert!(
                gpu.prim_object.iter().all(|&k| (k as usize) < gpu.objects.len()),
                "{name}"
            );
            assert!(
                gpu.objects.iter().all(|o| (o.material as usize) < gpu.materials.len()),
                "{name}"
            );
            assert!(!gpu.lights.is_empty(), "{name} has no light");
            match &gpu.instancing {
                None => assert!(gpu.lights.windows(2).all(|w| w[0] < w[1]), "{name}"),
                Some(i) => assert_eq!(i.light_objects.len(), gpu.lights.len(), "{name}"),
            }
            let finite = |v: &[f32; 4]| v.iter().all(|x| x.is_finite());
            assert!(
                gpu.model_tris.iter().all(|t| [t.v0, t.v1, t.v2].iter().all(finite)),
                "{name}"
            );
            assert!(gpu
                .model_tris
                .iter()
                .all(|t| t.v0[3] == 0.0 && t.v1[3] == 0.0 && t.v2[3] == 0.0));
            assert!(
                gpu.objects
                    .iter()
                    .all(|o| o.rows.iter().all(finite) && o.radius_scale > 0.0),
                "{name}"
            );
            let frame = scene.frame(&gpu);
            assert_eq!(frame.n_prims as usize, tris + spheres, "{name}");
            assert_eq!(frame.n_lights as usize, gpu.lights.len(), "{name}");
        }
    }

    #[test]
    fn the_forest_is_a_billion_instanced_triangles_that_cannot_be_flattened() {
        let scene = Scene::builtin("forest").unwrap();
        let (tris, _) = scene.counts();
        assert!(
            scene.objects.len() >= 10_000 && tris >= 1_000_000_000,
            "{} {tris}",
            scene.objects.len()
        );
        let moving = scene
            .objects
            .iter()
            .filter(|o| o.animation != Animation::default())
            .count();
        assert!(moving > 100 && moving < scene.objects.len() / 4, "{moving}");
        let gpu = scene.gpu_data_as(0.0, InstancingMode::Auto).unwrap();
        let i = gpu.instancing.as_ref().expect("instanced");
        let (instanced, distinct) = i.counts();
        assert_eq!(instanced, tris as u64 + 1);
        assert!(distinct < 200_000, "{distinct}");
        // The waving pond: the world-space group, transformed every frame.
        assert_eq!(i.world_tris, 2 * 160 * 96);
        assert!(
            gpu.instancing_why.contains("1 in the world-space group"),
            "{}",
            gpu.instancing_why
        );
        // Three meshes and a sphere besides the bunny and the ground's quad.
        assert!(scene.meshes.len() >= 4);
        let e = scene.gpu_data_as(0.0, InstancingMode::Off).unwrap_err();
        assert!(e.contains("instance them") && e.contains("GB"), "{e}");
        // The canopy and the trunk are closed and face outward (positive signed volume).
        for m in ["builtin:canopy", "builtin:trunk"] {
            let mesh = scene.meshes.iter().find(|x| x.name == m).unwrap();
            let volume: f64 = mesh
                .tris
                .iter()
                .map(|t| {
                    let v = |p: [f32; 4]| glam::DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                    v(t.v0).dot(v(t.v1).cross(v(t.v2))) / 6.0
                })
                .sum();
            assert!(volume > 0.0, "{m}: {volume}");
        }
    }

    #[test]
    fn cornell_light_triangles_are_lights_and_walls_face_inwards() {
        let scene = Scene::builtin("cornell").unwrap();
        let gpu = scene.gpu_data(0.0);
        let light = scene.objects.iter().position(|o| o.name == "light").unwrap() as u32;
        let light_prims: Vec<u32> = (0..gpu.prim_object.len() as u32)
            .filter(|&i| gpu.prim_object[i as usize] == light)
            .collect();
        assert_eq!(light_prims.len(), 2);
        assert_eq!(gpu.lights, light_prims);
        let centre = Vec3::splat(BOX / 2.0);
        for (i, t) in gpu.model_tris.iter().enumerate() {
            let o = &gpu.objects[gpu.prim_object[i] as usize];
            let [a, b, c] = [t.v0, t.v1, t.v2].map(|v| world(o, v));
            let normal = (b - a).cross(c - a);
            for p in [a, b, c] {
                assert!(
                    p.min_element() > -1e-3 && p.max_element() < BOX + 1e-3,
                    "{p} outside the box"
                );
            }
            let name = &scene.objects[gpu.prim_object[i] as usize].name;
            if name.contains("wall") || name == "floor" || name == "ceiling" || name == "light" {
                assert!(normal.dot(centre - a) > 0.0, "{name} faces out of the box");
            }
            if name == "light" {
                assert!(normal.normalize().dot(-Vec3::Y) > 0.999);
                assert!((a.y - 554.0).abs() < 1e-3);
            }
        }
        // The tall block stands on the floor, as in the book: corner (265, 0, 295), turned 15 degrees.
        let tall = scene.objects.iter().position(|o| o.name == "tall block").unwrap();
        let o = &gpu.objects[tall];
        let corner = world(o, [-0.5, -0.5, -0.5, 0.0]);
        assert!((corner - Vec3::new(265.0, 0.0, 295.0)).length() < 1e-3, "{corner}");
        assert!((world(o, [0.5, 0.5, 0.5, 0.0]).y - 330.0).abs() < 1e-3);
    }

    #[test]
    fn held_meshes_stand_on_the_floor_in_the_middle() {
        for name in ["suzanne", "bunny"] {
            let scene = Scene::builtin(name).unwrap();
            let gpu = scene.gpu_data(0.0);
            let k = scene.objects.iter().position(|o| o.name == name).unwrap();
            let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for (t, _) in gpu
                .model_tris
                .iter()
                .zip(&gpu.prim_object)
                .filter(|(_, &o)| o as usize == k)
            {
                for v in [t.v0, t.v1, t.v2] {
                    let p = world(&gpu.objects[k], v);
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
            assert!(lo.y.abs() < 1e-2, "{name}: lowest point {lo}");
            assert!(
                ((hi - lo).max_element() - 300.0).abs() < 1e-2,
                "{name}: size {}",
                hi - lo
            );
            assert!(((lo.x + hi.x) / 2.0 - BOX / 2.0).abs() < 1e-2 && ((lo.z + hi.z) / 2.0 - BOX / 2.0).abs() < 1e-2);
        }
    }

    #[test]
    fn instances_hold_over_a_million_triangles_that_spin() {
        let scene = Scene::builtin("instances").unwrap();
        let (tris, _) = scene.counts();
        assert!(tris >= 1_000_000, "{tris}");
        assert_eq!(scene.meshes.iter().filter(|m| m.name == "bunny.obj").count(), 1);
        let bunnies: Vec<&SceneObject> = scene.objects.iter().filter(|o| o.name.starts_with("bunny")).collect();
        assert_eq!(bunnies.len(), 16);
        let speeds: std::collections::HashSet<i32> =
            bunnies.iter().map(|o| o.animation.spin_deg_per_s.y as i32).collect();
        assert_eq!(speeds.len(), 16);
        assert_ne!(scene.gpu_data(0.0).objects[1], scene.gpu_data(1.0).objects[1]);
    }

    #[test]
    fn spheres_follow_the_book() {
        let scene = Scene::builtin("spheres").unwrap();
        let (tris, spheres) = scene.counts();
        assert_eq!(tris, 0);
        assert!(spheres > 400 && spheres <= 22 * 22 + 5, "{spheres}");
        let gpu = scene.gpu_data(0.0);
        let light = scene.objects.iter().position(|o| o.name == "light").unwrap() as u32;
        assert_eq!(
            gpu.lights,
            vec![gpu.prim_object.iter().position(|&k| k == light).unwrap() as u32]
        );
        assert_eq!(gpu.objects[0].rows.map(|r| r[3]), [0.0, -1000.0, 0.0]);
        assert_eq!(gpu.model_spheres[0].center_radius, [0.0, 0.0, 0.0, 1000.0]);
    }

    #[test]
    fn unknown_builtin_lists_the_builtins() {
        let e = Scene::builtin("teapot").unwrap_err().to_string();
        assert!(
            e.contains("teapot") && e.contains("cornell, suzanne, bunny, spheres, instances"),
            "{e}"
        );
        let e = Scene::open("teapot").unwrap_err().to_string();
        assert!(e.contains("teapot") && e.contains("cornell"), "{e}");
    }
}
