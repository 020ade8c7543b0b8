//! `raytrace`: the command-line front end; the commands are `raytrace::cli`'s.
fn main() -> anyhow::Result<()> {
    raytrace::cli::run()
}
