//! `morph liken OUT`: the last frame's silhouettes and tips against the target, from the
//! written files alone, as JSON.

use super::fail;
use clap::{Args, ValueEnum};
use morph::output::WrittenSurface;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub struct LikenArgs {
    /// A morph's output folder.
    output: PathBuf,
    /// Which surface's last frame to liken to the target.
    #[arg(long, value_enum, default_value_t = Surface::Rebuilt)]
    surface: Surface,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Surface {
    /// `meshes/`, rebuilt from the particles.
    Rebuilt,
    /// `carried/`, the source's own mesh carried by the particles.
    Carried,
}

pub fn run(args: &LikenArgs) -> ExitCode {
    let surface = match args.surface {
        Surface::Rebuilt => WrittenSurface::Rebuilt,
        Surface::Carried => WrittenSurface::Carried,
    };
    match morph::output::written_likeness(&args.output, surface) {
        Ok(l) => {
            say!(
                "{}",
                serde_json::to_string_pretty(&l).expect("plain report")
            );
            ExitCode::SUCCESS
        }
        Err(e) => fail(false, 1, &e.to_string()),
    }
}
