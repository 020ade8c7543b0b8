//! Simulate only what the scene calls for. From a scene's content this derives which path
//! tracer features it needs (primitive kinds, next-event estimation, metal, glass, thin
//! lens) and the depth a path can actually reach; the frame carries the decision
//! (`Frame::features`, `Frame::max_depth`), the GPU runs `path_trace` specialised to it and
//! the CPU executor tests the same bits. A user can force features on or off; every decision
//! keeps its reason for `raytrace render --explain`.
use crate::scene::SceneGpu;
use anyhow::{bail, Result};
use shared::types::{
    Frame, MaterialKind, ALPHA_BLEND, ALPHA_MASK, FEATURES_ALL, FEATURE_ALPHA, FEATURE_DIELECTRIC, FEATURE_ENVMAP,
    FEATURE_GUIDES, FEATURE_INSTANCES, FEATURE_METAL, FEATURE_NEE, FEATURE_NORMAL_MAPS, FEATURE_PBR, FEATURE_PUNCTUAL,
    FEATURE_SHADING_NORMALS, FEATURE_SPHERES, FEATURE_TEXTURES, FEATURE_THIN_LENS, FEATURE_TRIANGLES, FLAG_DENOISE,
    FLAG_NEE, INVALID, TEX_NORMAL,
};
use std::fmt::Write;

/// Feature names as `--features` takes them, with their bits.
pub const NAMES: [(&str, u32); 13] = [
    ("triangles", FEATURE_TRIANGLES),
    ("spheres", FEATURE_SPHERES),
    ("nee", FEATURE_NEE),
    ("metal", FEATURE_METAL),
    ("dielectric", FEATURE_DIELECTRIC),
    ("thin-lens", FEATURE_THIN_LENS),
    ("shading-normals", FEATURE_SHADING_NORMALS),
    ("punctual", FEATURE_PUNCTUAL),
    ("pbr", FEATURE_PBR),
    ("textures", FEATURE_TEXTURES),
    ("normal-maps", FEATURE_NORMAL_MAPS),
    ("envmap", FEATURE_ENVMAP),
    ("alpha", FEATURE_ALPHA),
];

/// What the user asked for beyond the scene's own needs.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Forced {
    /// Run the all-features kernel at the scene's depth (no specialisation at all).
    pub all: bool,
    pub on: u32,
    pub off: u32,
}

impl Forced {
    /// Parses `all` or a list of `+name` / `-name` (names of [`NAMES`]).
    pub fn parse(items: &[String]) -> Result<Forced> {
        let mut f = Forced::default();
        for item in items {
            let item = item.trim();
            if item == "all" {
                f.all = true;
                continue;
            }
            let (on, name) = match item.split_at_checked(1) {
                Some(("+", n)) => (true, n),
                Some(("-", n)) => (false, n),
                _ => bail!("feature {item:?}: write +NAME or -NAME (or all)"),
            };
            let Some(&(_, bit)) = NAMES.iter().find(|(n, _)| *n == name) else {
                let names: Vec<_> = NAMES.iter().map(|(n, _)| *n).collect();
                bail!("unknown feature {name:?}; features are {}", names.join(", "));
            };
            if on {
                f.on |= bit;
            } else {
                f.off |= bit;
            }
        }
        if f.on & f.off != 0 {
            bail!("a feature is forced both on and off");
        }
        Ok(f)
    }
}

/// One decision and its reason.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Decision {
    pub feature: String,
    /// "on", "off", or the value chosen (max depth).
    pub state: String,
    pub why: String,
}

/// The features a frame runs with.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Features {
    pub bits: u32,
    /// The maximum depth worth tracing.
    pub depth: u32,
    pub decisions: Vec<Decision>,
}

impl Features {
    /// `frame` running with these features.
    pub fn apply(&self, frame: &Frame) -> Frame {
        let mut f = *frame;
        f.features = self.bits;
        f.max_depth = self.depth;
        f
    }

    /// The decisions as an aligned table.
    pub fn explain(&self) -> String {
        let mut s = String::new();
        for d in &self.decisions {
            let _ = writeln!(s, "  {:<15} {:<4} {}", d.feature, d.state, d.why);
        }
        s
    }

    /// Names of the features on, or "all".
    pub fn summary(&self) -> String {
        if self.bits == FEATURES_ALL {
            return "all".into();
        }
        let on: Vec<_> = NAMES
            .iter()
            .filter(|(_, b)| self.bits & b != 0)
            .map(|(n, _)| *n)
            .collect();
        on.join("+")
    }
}

fn plural(n: usize, what: &str) -> String {
    format!("{n} {what}{}", if n == 1 { "" } else { "s" })
}

/// Derives the features `frame` (as `Scene::frame` made it) needs for `data`, then applies
/// `forced`. Forcing off a primitive kind the scene contains is an error (its primitives
/// would be skipped by the traversal but not by the light sampling).
pub fn derive(data: &SceneGpu, frame: &Frame, forced: &Forced) -> Result<Features> {
    let n_tris = data.model_tris.len();
    let n_spheres = data.model_spheres.len();
    let kind_of = |o: &shared::types::Object| data.materials.get(o.material as usize);
    let count_kind = |k: MaterialKind| {
        data.objects
            .iter()
            .filter(|o| kind_of(o).is_some_and(|m| m.kind == k as u32))
            .count()
    };
    let metal = count_kind(MaterialKind::Metal);
    let glass = count_kind(MaterialKind::Dielectric);
    let pbr = count_kind(MaterialKind::Pbr);
    // Surfaces next-event estimation lights: Lambert and GGX.
    let diffuse = count_kind(MaterialKind::Diffuse) + pbr;
    let punctual = data.punctual.len();
    let lights = data.lights.len() + punctual;
    let lens = frame.camera.u[3];
    let nee_asked = frame.flags & FLAG_NEE != 0;

    let mut decisions = Vec::new();
    let mut bits = 0;
    let mut decide = |name: &str, bit: u32, on: bool, why: String| {
        let (on, why) = if forced.all {
            (true, format!("forced on (all features); scene: {why}"))
        } else if forced.on & bit != 0 {
            (true, format!("forced on; scene: {why}"))
        } else if forced.off & bit != 0 {
            (false, format!("forced off; scene: {why}"))
        } else {
            (on, why)
        };
        if on {
            bits |= bit;
        }
        decisions.push(Decision {
            feature: name.into(),
            state: (if on { "on" } else { "off" }).into(),
            why,
        });
    };
    let counted = [
        ("triangles", FEATURE_TRIANGLES, n_tris, "triangle"),
        ("spheres", FEATURE_SPHERES, n_spheres, "sphere"),
        ("metal", FEATURE_METAL, metal, "metal object"),
        ("dielectric", FEATURE_DIELECTRIC, glass, "glass object"),
        ("pbr", FEATURE_PBR, pbr, "metallic-roughness object"),
    ];
    for (name, bit, n, what) in counted {
        decide(
            name,
            bit,
            n > 0,
            if n > 0 { plural(n, what) } else { format!("no {what}s") },
        );
    }
    let nee_why = match (lights, nee_asked) {
        (0, _) => "no emissive surfaces to sample".to_string(),
        (n, false) => format!("switched off ({} present)", plural(n, "light")),
        (n, true) if diffuse == 0 => format!("no diffuse surfaces to light ({} present)", plural(n, "light")),
        (_, true) => format!(
            "{} toward {} and {}",
            plural(diffuse, "diffuse object"),
            plural(data.lights.len(), "emissive primitive"),
            plural(punctual, "punctual light")
        ),
    };
    let nee = lights > 0 && nee_asked && diffuse > 0;
    decide("nee", FEATURE_NEE, nee, nee_why);
    decide(
        "punctual",
        FEATURE_PUNCTUAL,
        nee && punctual > 0,
        match (punctual, nee) {
            (0, _) => "no punctual lights".into(),
            (n, true) => plural(n, "punctual light"),
            (n, false) => format!(
                "{} unseen: they are reached by next-event estimation only",
                plural(n, "punctual light")
            ),
        },
    );
    decide(
        "thin-lens",
        FEATURE_THIN_LENS,
        lens > 0.0,
        if lens > 0.0 {
            format!("aperture {}", 2.0 * lens)
        } else {
            "pinhole camera (aperture 0)".into()
        },
    );
    let textured = |slot: usize| {
        data.objects
            .iter()
            .filter(|o| kind_of(o).is_some_and(|m| m.textures[slot] != 0))
            .count()
    };
    let with_textures = (0..4).map(textured).max().unwrap_or(0);
    decide(
        "textures",
        FEATURE_TEXTURES,
        with_textures > 0,
        if with_textures > 0 {
            format!("{} with textures", plural(with_textures, "object"))
        } else {
            "no textures".into()
        },
    );
    let normal_mapped = textured(TEX_NORMAL);
    decide(
        "normal-maps",
        FEATURE_NORMAL_MAPS,
        normal_mapped > 0,
        if normal_mapped > 0 {
            format!("{} with normal maps", plural(normal_mapped, "object"))
        } else {
            "no normal maps".into()
        },
    );
    decide(
        "envmap",
        FEATURE_ENVMAP,
        data.env.is_some(),
        match &data.env {
            Some(e) => format!("environment map {}", e.source),
            None => "no environment map (the sky gradient)".into(),
        },
    );
    let alpha_mode = |mode: u32| {
        data.objects
            .iter()
            .filter(|o| kind_of(o).is_some_and(|m| m.alpha_mode == mode))
            .count()
    };
    let (masked, blended) = (alpha_mode(ALPHA_MASK), alpha_mode(ALPHA_BLEND));
    decide(
        "alpha",
        FEATURE_ALPHA,
        masked + blended > 0,
        if masked + blended > 0 {
            format!(
                "{} alpha-masked, {} blended",
                plural(masked, "object"),
                plural(blended, "object")
            )
        } else {
            "every surface opaque".into()
        },
    );
    let smooth = if crate::scene::attrs::has_normals(&data.attrs) {
        data.objects.iter().filter(|o| o.attrs != INVALID).count()
    } else {
        0
    };
    decide(
        "shading-normals",
        FEATURE_SHADING_NORMALS,
        smooth > 0,
        if smooth > 0 {
            format!("{} with vertex normals", plural(smooth, "mesh object"))
        } else {
            "no vertex normals (flat shading)".into()
        },
    );
    let contains = |bit: u32, n: usize, what: &str| -> Result<()> {
        if bits & bit == 0 && n > 0 {
            bail!(
                "the scene has {}: {what} cannot be left out",
                plural(n, what.trim_end_matches('s'))
            );
        }
        Ok(())
    };
    contains(FEATURE_TRIANGLES, n_tris, "triangles")?;
    contains(FEATURE_SPHERES, n_spheres, "spheres")?;
    // The layout's, not a feature: not forced by `--features`, not in the all-features kernel.
    let instanced = data.instancing.is_some();
    if instanced {
        bits |= FEATURE_INSTANCES;
    }
    if !data.instancing_why.is_empty() {
        decisions.push(Decision {
            feature: "instances".into(),
            state: (if instanced { "on" } else { "off" }).into(),
            why: data.instancing_why.clone(),
        });
    }
    // Not a scene's feature but the frame's: not forced by `--features`, and not part of
    // the all-features kernel.
    let denoise = frame.flags & FLAG_DENOISE != 0;
    if denoise {
        bits |= FEATURE_GUIDES;
    }
    decisions.push(Decision {
        feature: "guides".into(),
        state: (if denoise { "on" } else { "off" }).into(),
        why: if denoise {
            "the denoiser reads the first hits' albedo, normal, distance, object and motion".into()
        } else {
            "no denoiser (--denoise)".into()
        },
    });

    // A path continues only off surfaces that scatter; without any, the first hit ends it.
    let scatters = data.objects.iter().any(|o| {
        kind_of(o).is_some_and(|m| {
            let k = m.kind;
            (k == MaterialKind::Diffuse as u32 && m.albedo[..3].iter().any(|&a| a > 0.0))
                || (k == MaterialKind::Metal as u32 && bits & FEATURE_METAL != 0)
                || (k == MaterialKind::Dielectric as u32 && bits & FEATURE_DIELECTRIC != 0)
                || (k == MaterialKind::Pbr as u32 && bits & FEATURE_PBR != 0)
        })
    });
    let emits = lights > 0
        || frame.sky_top[..3]
            .iter()
            .chain(&frame.sky_bottom[..3])
            .any(|&s| s > 0.0);
    let (depth, why) = if forced.all {
        (frame.max_depth, "as asked (all features)".to_string())
    } else if !emits {
        (
            1,
            "nothing emits light (no emissive surfaces, black sky): one bounce shows it".into(),
        )
    } else if !scatters {
        (1, "no surface scatters light: paths end at the first hit".into())
    } else {
        (frame.max_depth, "as asked (the scene scatters light)".into())
    };
    decisions.push(Decision {
        feature: "max depth".into(),
        state: depth.min(frame.max_depth).to_string(),
        why,
    });
    Ok(Features {
        bits,
        depth: depth.min(frame.max_depth),
        decisions,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;

    fn features(scene: &str, forced: &[&str]) -> Result<Features> {
        let s = Scene::builtin(scene)?;
        let data = s.gpu_data(0.0);
        let forced = Forced::parse(&forced.iter().map(|s| s.to_string()).collect::<Vec<_>>())?;
        derive(&data, &s.frame(&data), &forced)
    }

    #[test]
    fn the_cornell_box_needs_triangles_and_nee_only() {
        let f = features("cornell", &[]).unwrap();
        assert_eq!(f.bits, FEATURE_TRIANGLES | FEATURE_NEE, "{}", f.explain());
        assert_eq!(f.depth, 16);
        assert!(f.explain().contains("no spheres"), "{}", f.explain());
    }

    #[test]
    fn the_spheres_scene_needs_its_materials() {
        let f = features("spheres", &[]).unwrap();
        for bit in [FEATURE_SPHERES, FEATURE_METAL, FEATURE_DIELECTRIC] {
            assert!(f.bits & bit != 0, "{}", f.explain());
        }
    }

    #[test]
    fn forcing_works_and_bad_forcing_is_named() {
        let f = features("cornell", &["+spheres", "-nee"]).unwrap();
        assert_eq!(f.bits, FEATURE_TRIANGLES | FEATURE_SPHERES);
        assert!(f.explain().contains("forced off"));
        assert_eq!(features("cornell", &["all"]).unwrap().bits, FEATURES_ALL);
        let e = features("cornell", &["-triangles"]).unwrap_err().to_string();
        assert!(e.contains("triangles cannot be left out"), "{e}");
        for bad in ["nee", "+glass", "+nee,-nee"] {
            let items: Vec<String> = bad.split(',').map(String::from).collect();
            assert!(Forced::parse(&items).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_scene_without_light_or_scattering_needs_one_bounce() {
        let s = Scene::builtin("cornell").unwrap();
        let mut data = s.gpu_data(0.0);
        let frame = s.frame(&data);
        data.lights.clear();
        let f = derive(&data, &frame, &Forced::default()).unwrap();
        assert_eq!(f.depth, 1, "{}", f.explain());
        assert_eq!(f.bits & FEATURE_NEE, 0);
    }
}
