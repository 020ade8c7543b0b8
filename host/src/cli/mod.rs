//! The command line: `raytrace`'s commands.
mod render;

pub use render::*;
