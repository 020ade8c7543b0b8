//! The meshes the built-in scenes need (`scene::builtin`: Suzanne, the bunny), built into the
//! binary, so that a `raytrace` installed with `cargo install --path host` renders them
//! without the source tree. [`crate::inputs::load_obj`] reads a copy where the assets folder
//! lacks the file; the folder (`RAYTRACE_ASSETS`, `./assets`, the source tree's) comes first.
use std::path::Path;

/// The built-in copies, by file name (2.6 MB; `assets/README.md` says where they come from).
pub const FILES: [(&str, &[u8]); 2] = [
    ("bunny.obj", include_bytes!("../../../assets/bunny.obj")),
    ("suzanne.obj", include_bytes!("../../../assets/suzanne.obj")),
];

/// The built-in copy of file `name`.
pub fn get(name: &str) -> Option<&'static [u8]> {
    FILES.iter().find(|(n, _)| *n == name).map(|&(_, bytes)| bytes)
}

/// The built-in copy to read for `path`: where `path` is a file of the assets folder `assets`
/// that does not exist and a copy of it is built in.
pub fn instead_of(path: &Path, assets: &Path) -> Option<&'static [u8]> {
    if path.parent() != Some(assets) || path.exists() {
        return None;
    }
    get(path.file_name()?.to_str()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_stand_in_only_for_missing_files_of_the_assets_folder() {
        let empty = std::env::temp_dir().join(format!("raytrace-builtin-assets-{}", std::process::id()));
        std::fs::create_dir_all(&empty).unwrap();
        assert!(instead_of(&empty.join("bunny.obj"), &empty).is_some());
        assert!(instead_of(&empty.join("suzanne.obj"), &empty).is_some());
        assert!(instead_of(&empty.join("teapot.obj"), &empty).is_none());
        assert!(instead_of(&empty.join("bunny.obj"), Path::new("/elsewhere")).is_none());
        let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        assert!(instead_of(&source.join("bunny.obj"), &source).is_none());
        for (name, bytes) in FILES {
            assert_eq!(std::fs::read(source.join(name)).unwrap(), bytes, "{name}");
        }
    }
}
