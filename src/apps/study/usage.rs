//! Resource use of this process, for the study's per-configuration figures: CPU seconds
//! (`getrusage`, all threads) and peak resident memory (Linux: `VmHWM` in `/proc/self/status`,
//! reset before each configuration by writing 5 to `/proc/self/clear_refs`). Elsewhere the
//! figures are absent rather than wrong.

/// User + system CPU seconds of the process so far.
pub fn cpu_seconds() -> Option<f64> {
    // SAFETY: getrusage writes into the zeroed struct we own.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let rc = unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) };
    (rc == 0).then(|| {
        let t = |tv: libc::timeval| tv.tv_sec as f64 + tv.tv_usec as f64 * 1e-6;
        t(usage.ru_utime) + t(usage.ru_stime)
    })
}

/// Resets the peak resident memory to the current one (Linux); a no-op elsewhere.
pub fn reset_peak() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Peak resident memory since the last [`reset_peak`], in MB (Linux).
pub fn peak_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}
