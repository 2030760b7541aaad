//! `morph assets`: writes the built-in meshes.

use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub struct AssetsArgs {
    /// Destination folder.
    #[arg(short, long, default_value = "assets")]
    output: PathBuf,
    /// Replace existing files of the same names.
    #[arg(long)]
    overwrite: bool,
}

pub fn run(args: &AssetsArgs) -> ExitCode {
    let written = morph::geometry::assets::write_builtin(&args.output, args.overwrite)
        .map(|paths| {
            for p in paths {
                println!("{}", p.display());
            }
        })
        .map_err(|e| anyhow::anyhow!("cannot write assets into '{}': {e}", args.output.display()));
    super::report(written)
}
