//! Resource use of this process, for the study's per-configuration figures and the manifest's
//! peak memory: CPU seconds
//! (`getrusage`, all threads) and peak resident memory (Linux: `VmHWM` in `/proc/self/status`,
//! reset before each configuration by writing 5 to `/proc/self/clear_refs`). Elsewhere the
//! figures are absent rather than wrong.
//!
//! The reset sets the peak to what the process holds now, and glibc's allocator keeps memory
//! an earlier, larger configuration freed (its arenas, below a threshold that grows with the
//! blocks freed): a 5,000-particle run measured after a 16,669-particle one reported that
//! one's 600 MB. So the freed memory goes back to the system first (`malloc_trim`).

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
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free heap pages to the system.
    unsafe {
        libc::malloc_trim(0);
    }
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Peak resident memory since the last [`reset_peak`], in MB (Linux).
pub fn peak_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}
