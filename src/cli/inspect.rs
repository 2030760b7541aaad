//! `morph inspect MESH`: what morph makes of a mesh, as JSON.

use super::{defaults, fail, help};
use clap::Args;
use morph::settings::limits;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub struct InspectArgs {
    /// The mesh file.
    mesh: PathBuf,
    #[arg(long, default_value_t = defaults().body.resolution as u16,
          value_parser = clap::value_parser!(u16).range(*limits::RESOLUTION.start() as i64..=*limits::RESOLUTION.end() as i64),
          help = help("Grid cells across the domain's longest side", Some(limits::RESOLUTION), defaults().body.resolution))]
    resolution: u16,
}

pub fn run(args: &InspectArgs) -> ExitCode {
    match morph::geometry::inspect(&args.mesh, args.resolution as usize) {
        Ok(report) => {
            for w in &report.warnings {
                eprintln!("morph: warning: {w}");
            }
            println!(
                "{}",
                serde_json::to_string_pretty(&report).expect("plain report")
            );
            ExitCode::SUCCESS
        }
        Err(e @ morph::geometry::MeshError::BadOption(_)) => fail(false, 2, &e.to_string()),
        Err(e) => fail(false, 1, &e.to_string()),
    }
}
