//! The binary as `cargo install --path host` leaves it: `raytrace --version` names the commit
//! it was built from.
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
