//! `morph compare A B`: two nodal mass grids, equal within tolerance or not.

use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

/// Compare two nodal mass grids (final_mass.mgrid); exit 0 if equal within tolerance.
#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The grid to check.
    a: PathBuf,
    /// The reference grid.
    b: PathBuf,
    /// Relative tolerance.
    #[arg(long, default_value_t = 1e-5)]
    rtol: f64,
    /// Absolute tolerance.
    #[arg(long, default_value_t = 1e-8)]
    atol: f64,
}

pub fn run(args: &CompareArgs) -> ExitCode {
    let (a, b, rtol, atol) = (args.a.as_path(), args.b.as_path(), args.rtol, args.atol);
    use morph::io::massgrid::{MassGrid, compare};
    if !(rtol.is_finite() && rtol >= 0.0 && atol.is_finite() && atol >= 0.0) {
        eprintln!("morph: error: --rtol and --atol must be finite and >= 0");
        return ExitCode::from(2);
    }
    let (ga, gb) = match (MassGrid::read(a), MassGrid::read(b)) {
        (Ok(x), Ok(y)) => (x, y),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("morph: error: {e}");
            return ExitCode::from(2);
        }
    };
    match compare(&ga, &gb, rtol, atol) {
        Ok(c) => {
            println!("{}", serde_json::to_string(&c).expect("plain struct"));
            if let Some(n) = &c.non_finite {
                eprintln!(
                    "morph: error: non-finite mass at node {:?} (index {}): {} vs {} ({} such nodes)",
                    n.node, n.index, n.a, n.b, n.count
                );
            }
            if c.within_tolerance {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            }
        }
        Err(e) => {
            println!(
                "{}",
                serde_json::json!({ "within_tolerance": false, "error": e })
            );
            eprintln!("morph: error: {e}");
            ExitCode::FAILURE
        }
    }
}
