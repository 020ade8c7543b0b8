//! The binary as `cargo install --path host` leaves it: `raytrace --version` names the commit
//! it was built from, and the built-in scenes render without the source tree's assets.
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_raytrace");

#[test]
fn version_names_the_commit() {
    let o = Command::new(BIN).arg("--version").output().expect("running raytrace");
    assert!(o.status.success());
    let line = String::from_utf8_lossy(&o.stdout).trim().to_string();
    let head = Command::new("git")
        .args(["-C", env!("CARGO_MANIFEST_DIR"), "rev-parse", "--short", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    let expected = format!("raytrace {} (", env!("CARGO_PKG_VERSION"));
    assert!(line.starts_with(&expected) && line.ends_with(')'), "{line}");
    match head {
        Some(hash) => {
            let date = line.trim_end_matches(')').rsplit(' ').next().unwrap_or("");
            assert!(line.contains(&format!("({hash} ")), "{line} does not name {hash}");
            assert!(
                date.len() == 10 && date.chars().filter(|&c| c == '-').count() == 2,
                "{line}: no commit date"
            );
        }
        None => assert!(line.ends_with("(unknown commit)"), "{line}"),
    }
}

#[test]
fn builtin_scenes_render_without_an_assets_folder() {
    let tmp = std::env::temp_dir().join(format!("raytrace-installed-{}", std::process::id()));
    let (empty, elsewhere) = (tmp.join("assets"), tmp.join("work"));
    std::fs::create_dir_all(&empty).expect("creating a temporary folder");
    std::fs::create_dir_all(&elsewhere).expect("creating a temporary folder");
    for scene in ["bunny", "suzanne"] {
        let out = elsewhere.join(format!("{scene}.png"));
        let o = Command::new(BIN)
            .args([
                "render",
                scene,
                "--backend",
                "cpu",
                "--size",
                "8x8",
                "--spp",
                "1",
                "--depth",
                "1",
            ])
            .arg("--out")
            .arg(&out)
            .env("RAYTRACE_ASSETS", &empty)
            .current_dir(&elsewhere)
            .output()
            .expect("running raytrace");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{scene} failed without assets:\n{stderr}");
        assert!(out.exists(), "{scene}: no picture written");
    }
    let _ = std::fs::remove_dir_all(&tmp);
}
