//! The `morph` command line; everything lives in `cli/` (one file per subcommand) and the
//! library does the work.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
