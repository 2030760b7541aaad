//! Running `morph SOURCE TARGET`: the signals that stop it, the progress it shows (a bar on a
//! terminal, JSON lines with `--json`, Open Job Description's lines with `--progress openjd`)
//! and how it ends (the summary, an interruption, an error).

use super::{MorphArgs, ProgressShown};
use crate::cli::fail;
use indicatif::{ProgressBar, ProgressStyle};
use morph::MorphError;
use morph::MorphEvent;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicUsize;

/// SIGINT, SIGTERM and SIGHUP (a closed terminal or SSH session) set `stop` to the signal's
/// number: the run stops at its next evaluation and keeps its checkpoint. A second signal
/// while stopping exits at once, with its line (and, with `--json`, its `interrupted` event)
/// written from the handler: the checkpoint's files are written under temporary names and
/// renamed, so the last one a resume needs is whole. SIGPIPE is ignored so that a closed stdout
/// (a log reader that went away) is seen as a failed write, which stops the run the same way.
fn stop_on_signals(json: bool, staging: &std::path::Path) -> std::io::Result<Arc<AtomicUsize>> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    // SAFETY: setting one signal's disposition to "ignore" is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
    let stop = Arc::new(AtomicUsize::new(0));
    let stopping = Arc::new(std::sync::atomic::AtomicBool::new(false));
    for sig in [SIGINT, SIGTERM, SIGHUP] {
        let code = 128 + sig;
        let message = format!(
            "interrupted again by {} while stopping: exited at once; the last checkpoint in '{}', if one was written, is kept for --resume",
            signal_name(sig as usize),
            staging.display()
        );
        // Made now: the handler only writes bytes (no allocation, no lock).
        let line = format!("morph: {message}\n").into_bytes();
        let event = json.then(|| {
            let e = serde_json::json!({ "event": "interrupted", "signal": signal_name(sig as usize), "message": message, "exit_code": code });
            format!("{e}\n").into_bytes()
        });
        let again = Arc::clone(&stopping);
        let second = move || {
            if again.load(std::sync::atomic::Ordering::SeqCst) {
                // SAFETY: write(2) and _exit(2) are async-signal-safe; the buffers are owned
                // by this closure and never change.
                unsafe {
                    libc::write(2, line.as_ptr().cast(), line.len());
                    if let Some(e) = &event {
                        libc::write(1, e.as_ptr().cast(), e.len());
                    }
                    libc::_exit(code);
                }
            }
        };
        // SAFETY: the action does only async-signal-safe work (see above).
        unsafe { signal_hook::low_level::register(sig, second)? };
        signal_hook::flag::register(sig, Arc::clone(&stopping))?;
        signal_hook::flag::register_usize(sig, Arc::clone(&stop), sig as usize)?;
    }
    Ok(stop)
}

fn signal_name(signal: usize) -> &'static str {
    match signal as i32 {
        signal_hook::consts::SIGINT => "SIGINT",
        signal_hook::consts::SIGTERM => "SIGTERM",
        signal_hook::consts::SIGHUP => "SIGHUP (the terminal closed)",
        libc::SIGPIPE => "SIGPIPE (stdout was closed)",
        _ => "a signal",
    }
}
/// `morph SOURCE TARGET`: progress bars on a terminal, JSON lines with --json.
pub fn run(args: &MorphArgs) -> ExitCode {
    // Settings checked as they are made (`job`); the targets' count by the library.
    let (settings, source, targets) = match args.job() {
        Ok(j) => j,
        Err(e) => return fail_run(args, 2, &e),
    };
    let stop = match stop_on_signals(args.json, &morph::io::outdir::partial_dir(&args.output)) {
        Ok(s) => s,
        Err(e) => return fail_run(args, 1, &format!("cannot watch for signals: {e}")),
    };
    let mut progress = Progress::new(args, &stop);
    let request = morph::output::OutputRequest {
        out: &args.output,
        overwrite: args.overwrite,
        resume: args.resume,
        stop: Some(&stop),
        memory_limit: args.memory_limit,
        scene: args.scene.as_deref(),
        on_frame: None,
    };
    let result = morph::output::morph_to_folder(&settings, &source, &targets, &request, |e| {
        progress.on_event(e)
    });
    progress.bar.finish_and_clear();
    match result {
        Ok(summary) => super::report::written(args, &summary),
        Err(MorphError::Interrupted { signal, kept }) => interrupted(args, signal, kept),
        Err(e) => {
            let code = match e {
                MorphError::Settings(_)
                | MorphError::Mesh(morph::geometry::MeshError::BadOption(_)) => 2,
                _ => 1,
            };
            fail_run(args, code, &e.to_string())
        }
    }
}

/// What a run shows while it works.
struct Progress<'a> {
    args: &'a MorphArgs,
    stop: &'a AtomicUsize,
    openjd: bool,
    show_bar: bool,
    /// Open Job Description progress: the percent when its first decimal changes; 100 only
    /// once every file is written.
    meter: morph::progress::ProgressMeter,
    shown_percent: String,
    bar: ProgressBar,
    last_loss: f64,
}

impl<'a> Progress<'a> {
    fn new(args: &'a MorphArgs, stop: &'a AtomicUsize) -> Progress<'a> {
        use std::io::IsTerminal;
        let openjd = args.progress == ProgressShown::Openjd;
        Progress {
            args,
            stop,
            openjd,
            show_bar: !args.quiet && !args.json && !openjd && std::io::stderr().is_terminal(),
            meter: morph::progress::ProgressMeter::new(),
            shown_percent: String::new(),
            bar: ProgressBar::hidden(),
            last_loss: f64::NAN,
        }
    }

    fn on_event(&mut self, e: &MorphEvent) {
        if self.args.json {
            use std::io::Write;
            let line = serde_json::to_string(e).expect("plain event");
            if writeln!(std::io::stdout(), "{line}").is_err() {
                // Nobody reads the events any more: stop as for a signal, keeping the work.
                self.stop
                    .store(libc::SIGPIPE as usize, std::sync::atomic::Ordering::Relaxed);
            }
            return;
        }
        if self.openjd {
            self.openjd_lines(e);
        }
        self.terminal(e);
    }

    /// Open Job Description's `openjd_progress` and `openjd_status` lines.
    fn openjd_lines(&mut self, e: &MorphEvent) {
        let percent = format!("{:.1}", 100.0 * self.meter.observe(e).min(0.999));
        // With --resume, setup and a level's start know no progress yet (a resumed run's
        // starts at its checkpoint): shown from the first step or segment on, so it never
        // goes back. A fresh run starts at 0.
        let measured =
            !self.args.resume || !matches!(e, MorphEvent::Setup { .. } | MorphEvent::Level { .. });
        if measured && percent != self.shown_percent {
            say!("openjd_progress: {percent}");
            self.shown_percent = percent;
        }
        match e {
            MorphEvent::Setup {
                particles,
                segments,
                passes,
                ..
            } => say!(
                "openjd_status: morphing {particles} particles: {segments} segments x {passes} passes"
            ),
            MorphEvent::Level { level, levels, .. } => {
                say!("openjd_status: level {level} of {levels}")
            }
            MorphEvent::Segment { pass, segment, .. } => {
                let (passes, segments) = self.meter.level_plan();
                say!(
                    "openjd_status: pass {} of {passes}, segment {} of {segments} done",
                    pass + 1,
                    segment + 1
                )
            }
            MorphEvent::Done { .. } => say!("openjd_status: writing the whole-sequence files"),
            MorphEvent::Iteration { .. } => {}
        }
    }

    /// The warnings, and on a terminal the progress bar.
    fn terminal(&mut self, e: &MorphEvent) {
        let bar = &self.bar;
        match e {
            MorphEvent::Setup {
                particles,
                grid_cells,
                segments,
                passes,
                iterations,
                warnings,
                ..
            } => {
                if !self.args.quiet {
                    for w in warnings {
                        eprintln!("morph: warning: {w}");
                    }
                }
                if self.show_bar {
                    bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                    bar.set_length((segments * passes * iterations) as u64);
                    bar.set_style(
                        ProgressStyle::with_template(
                            "{elapsed_precise} [{bar:30}] {pos}/{len} evaluations  {msg}",
                        )
                        .expect("valid template")
                        .progress_chars("=> "),
                    );
                    bar.println(format!(
                        "morph: {particles} particles on a {}x{}x{} grid, {segments} segments x {passes} passes",
                        grid_cells[0], grid_cells[1], grid_cells[2]
                    ));
                }
            }
            MorphEvent::Iteration {
                pass,
                segment,
                loss,
                ..
            } => {
                if loss.is_finite() {
                    self.last_loss = *loss;
                }
                bar.inc(1);
                bar.set_message(format!(
                    "pass {}  segment {}  loss {:.4e}",
                    pass + 1,
                    segment + 1,
                    self.last_loss
                ));
            }
            MorphEvent::Level {
                level,
                levels,
                particles,
                grid_cells,
                segments,
                iterations,
            } => {
                if self.show_bar {
                    bar.set_position(0);
                    bar.set_length((segments * iterations) as u64);
                    bar.println(format!(
                        "morph: level {level} of {levels}: {particles} particles on a {}x{}x{} grid",
                        grid_cells[0], grid_cells[1], grid_cells[2]
                    ));
                }
            }
            MorphEvent::Segment { .. } | MorphEvent::Done { .. } => {}
        }
    }
}

/// A run stopped by a signal: exit 128 + the signal, and where the kept work is.
fn interrupted(args: &MorphArgs, signal: usize, kept: bool) -> ExitCode {
    let code = (128 + signal).min(255) as u8;
    let staging = morph::io::outdir::partial_dir(&args.output);
    let message = if kept {
        format!(
            "interrupted by {}: completed segments are kept in '{}'; run the same command with --resume to continue",
            signal_name(signal),
            staging.display()
        )
    } else {
        format!(
            "interrupted by {} before any segment completed; nothing was kept",
            signal_name(signal)
        )
    };
    eprintln!("morph: {message}");
    if args.json {
        say!(
            "{}",
            serde_json::json!({ "event": "interrupted", "signal": signal_name(signal), "message": message, "exit_code": code })
        );
    }
    ExitCode::from(code)
}

/// A failed run: the one-line error (and with `--json` its event, with `--progress openjd` the
/// farm's failure line).
fn fail_run(args: &MorphArgs, code: u8, message: &str) -> ExitCode {
    if args.progress == ProgressShown::Openjd {
        say!("openjd_fail: {message}");
    }
    fail(args.json, code, message)
}
