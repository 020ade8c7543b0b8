//! Why a scene could not be built. Every message starts with the scene file (or "built-in scene
//! NAME") and says what is wrong.
use super::Scene;

/// A scene that could not be read, parsed or accepted.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("{file}: cannot read the scene file: {error}")]
    Read { file: String, error: std::io::Error },
    /// TOML syntax, an unknown field or a value of the wrong type; `location` is
    /// "line L, column C: " when the TOML parser knows where.
    #[error("{file}: {location}{message}")]
    Toml {
        file: String,
        location: String,
        message: String,
    },
    /// An object names a material that `[materials]` does not define.
    #[error("{file}: {object} uses material \"{material}\", which is not defined (materials: {known})")]
    UnknownMaterial {
        file: String,
        object: String,
        material: String,
        known: String,
    },
    /// A material's `kind` is none of the known kinds.
    #[error(
        "{file}: material \"{material}\" has unknown kind \"{kind}\" (kinds: diffuse, metal, dielectric, emissive, pbr)"
    )]
    UnknownKind {
        file: String,
        material: String,
        kind: String,
    },
    /// A mesh file is missing or malformed, or a `builtin:` mesh is unknown.
    #[error("{file}: {object}: cannot load mesh \"{mesh}\": {message}")]
    Mesh {
        file: String,
        object: String,
        mesh: String,
        message: String,
    },
    /// A model file (OBJ, glTF, PLY) that cannot be read or used: `message` says why, starting
    /// with the line ("line 12: ...") where the parser knows it.
    #[error("{file}: {message}")]
    Model { file: String, message: String },
    /// An environment map that cannot be read or used.
    #[error("{file}: environment map: {message}")]
    Environment { file: String, message: String },
    /// The scene has no objects.
    #[error("{file}: the scene has no objects")]
    Empty { file: String },
    /// A value out of range: `what` names the camera, render settings, material or object,
    /// `problem` says what is wrong with it.
    #[error("{file}: {what}: {problem}")]
    Invalid {
        file: String,
        what: String,
        problem: String,
    },
    /// [`Scene::builtin`] was given a name that is not in [`Scene::BUILTINS`].
    #[error("unknown built-in scene \"{name}\" (built-ins: {})", Scene::BUILTINS.join(", "))]
    UnknownBuiltin { name: String },
    /// [`Scene::open`] was given neither a built-in name nor an existing file.
    #[error("{name}: no such scene file, and not a built-in scene either (built-ins: {})", Scene::BUILTINS.join(", "))]
    NotFound { name: String },
}

/// How messages name object `index`: `objects[2] ("ball")`.
pub(super) fn object_label(index: usize, name: &str) -> String {
    format!("objects[{index}] (\"{name}\")")
}
