//! `morph farm-template openjd`: a render farm's job template for a morph (the library's
//! `morph::farm`), from the same options as `morph` itself.

use super::morph::MorphArgs;
use clap::{Args, Parser, ValueEnum};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum FarmFormat {
    /// Open Job Description (JSON job template, jobtemplate-2023-09).
    Openjd,
}

#[derive(Args, Debug)]
pub struct FarmTemplateArgs {
    /// The template's format.
    format: FarmFormat,
    /// The template file to write.
    #[arg(long, default_value = "morph-job.json")]
    template: PathBuf,
    /// Replace the template file if it exists (before or after the meshes: the template's job
    /// always runs with --resume, so the morph's own --overwrite means this one).
    #[arg(long)]
    overwrite: bool,
    /// The morph: SOURCE TARGET... and any of `morph`'s options (see morph --help).
    #[arg(trailing_var_arg = true, allow_hyphen_values = true, required = true)]
    morph: Vec<String>,
}

/// The morph's own options, parsed as `morph` parses them.
#[derive(Parser, Debug)]
#[command(name = "morph", allow_negative_numbers = true)]
struct MorphCommand {
    #[command(flatten)]
    morph: MorphArgs,
}

pub fn run(args: &FarmTemplateArgs) -> ExitCode {
    let parsed = MorphCommand::try_parse_from(std::iter::once("morph".into()).chain(
        super::morph::knob_options_as_set(args.morph.iter().map(Into::into).collect()),
    ))
    .map_err(|e| {
        let text = e.render().to_string();
        let first = text
            .lines()
            .next()
            .unwrap_or("")
            .trim_start_matches("error: ");
        format!("farm-template: the morph's options: {first}")
    });
    let job = parsed.and_then(|c| {
        let (settings, source, targets) = c.morph.job()?;
        settings.validate_targets(targets.len())?;
        Ok((
            settings,
            source,
            targets,
            c.morph.output().to_path_buf(),
            c.morph.overwrite(),
        ))
    });
    let (settings, source, targets, out, overwrite_given_after) = match job {
        Ok(j) => j,
        Err(e) => return super::fail(false, 2, &e),
    };
    // Never the morph's own inputs, even with --overwrite.
    let same = |p: &std::path::Path| match (args.template.canonicalize(), p.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    let mut inputs: Vec<&std::path::Path> = vec![&source];
    inputs.extend(targets.iter().map(PathBuf::as_path));
    inputs.extend(settings.world.meshes());
    if let Some(input) = inputs.into_iter().find(|p| same(p)) {
        return super::fail(
            false,
            2,
            &format!(
                "the template '{}' would replace the morph's input '{}'; name another file",
                args.template.display(),
                input.display()
            ),
        );
    }
    if args.template.exists() && !(args.overwrite || overwrite_given_after) {
        return super::fail(
            false,
            2,
            &format!(
                "'{}' exists; pass --overwrite to replace it",
                args.template.display()
            ),
        );
    }
    let command = std::env::current_exe().unwrap_or_else(|_| PathBuf::from("morph"));
    let text = match args.format {
        FarmFormat::Openjd => {
            let dir = match args.template.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
                _ => PathBuf::from("."),
            };
            morph::farm::openjd_template(&settings, &source, &targets, &out, &command, &dir)
        }
    };
    match morph::io::write_atomically(&args.template, |w| {
        std::io::Write::write_all(w, text.as_bytes())
    }) {
        Ok(()) => {
            say!("{}", args.template.display());
            ExitCode::SUCCESS
        }
        Err(e) => super::fail(
            false,
            1,
            &format!("cannot write template '{}': {e}", args.template.display()),
        ),
    }
}
