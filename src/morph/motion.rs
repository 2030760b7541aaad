//! What a viewer sees of a morph's motion, measured from its frames (issue 27): does the body
//! pulse at segment boundaries, follow its easing curve, and come to rest?
//!
//! Let `s(f)` be the rms particle speed of frame `f`. Over the *active* frames, those from the
//! first to the last where `s` exceeds [`ACTIVE`] of its peak:
//! - **pulse**: the amplitude, at the segments' period, of `s` minus its moving average over
//!   one segment, divided by the mean of `s`;
//! - **dip**: the mean over segment boundaries of `1 - s(boundary) / mean s` of the frames
//!   within half a segment of it;
//! - **wobble**: the rms second difference of `s`, divided by the mean of `s`;
//! - **settle**: `s` on the last frame over the peak of `s`;
//! - **ease error**: the largest gap between progress (the gain in IoU with the target's inside
//!   on a lattice of [`PROGRESS_ACROSS`] points, 0 on the first frame, 1 on the last) and
//!   `smoothstep((f - 1) / (arrive - 1))` (1 from the arrival frame on);
//! - **frozen frames**: frames before the first active one.

use serde::{Deserialize, Serialize};

/// A frame is active when its rms speed exceeds this share of the peak.
pub const ACTIVE: f64 = 0.05;
/// Lattice points along the longest side of the box progress is measured on.
pub const PROGRESS_ACROSS: usize = 40;

/// The motion measures of a run, or of one keyframe's section of it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MotionMeasures {
    pub pulse: f64,
    pub dip: f64,
    pub wobble: f64,
    pub settle: f64,
    /// Absent when progress was not measured (or the shape did not change at all).
    pub ease_error: Option<f64>,
    pub frozen_frames: usize,
    /// Frames measured, and the frames per segment the pulse and dip look for.
    pub frames: usize,
    pub frames_per_segment: f64,
    /// The first frame measured (1-based; the frame the shape change begins on for a whole
    /// run, the previous keyframe's for a later section).
    #[serde(default = "first_frame")]
    pub first_frame: usize,
}

fn first_frame() -> usize {
    1
}

/// Measures frames `speeds[i]` (frame `i + 1`), with `iou[i]` the IoU with the target's
/// inside on that frame (empty: no ease error), segment boundaries after the frames in
/// `boundaries` (1-based frame numbers where a segment ends), the target reached on frame
/// `arrive` (1-based, within the frames).
pub fn measure(
    speeds: &[f64],
    iou: &[f64],
    boundaries: &[usize],
    frames_per_segment: f64,
    arrive: usize,
) -> MotionMeasures {
    let n = speeds.len();
    let peak = speeds.iter().copied().fold(0.0, f64::max);
    let active: Vec<usize> = (0..n).filter(|&i| speeds[i] > ACTIVE * peak).collect();
    let (first, last) = match (active.first(), active.last()) {
        (Some(&a), Some(&b)) => (a, b),
        _ => (n, n),
    };
    let span: &[f64] = if first < n {
        &speeds[first..=last]
    } else {
        &[]
    };
    let mean = if span.is_empty() {
        0.0
    } else {
        span.iter().sum::<f64>() / span.len() as f64
    };
    let rel = |x: f64| if mean > 0.0 { x / mean } else { 0.0 };

    // Pulse: s minus its centred moving average over one segment, its Fourier amplitude at
    // the segment's period.
    let p = frames_per_segment.max(1.0);
    let half = (p / 2.0).floor() as isize;
    let pulse = if span.len() >= 3 {
        let residual: Vec<f64> = (0..span.len() as isize)
            .map(|i| {
                let lo = (i - half).max(0) as usize;
                let hi = ((i + half) as usize).min(span.len() - 1);
                let avg = span[lo..=hi].iter().sum::<f64>() / (hi - lo + 1) as f64;
                span[i as usize] - avg
            })
            .collect();
        let w = 2.0 * std::f64::consts::PI / p;
        let (mut re, mut im) = (0.0, 0.0);
        for (i, r) in residual.iter().enumerate() {
            let frame = (first + i + 1) as f64;
            re += r * (w * frame).cos();
            im += r * (w * frame).sin();
        }
        rel(2.0 * (re * re + im * im).sqrt() / residual.len() as f64)
    } else {
        0.0
    };

    // Dip: the speed at each boundary inside the active frames against the frames around it.
    let dips: Vec<f64> = boundaries
        .iter()
        .filter(|&&b| b >= first + 2 && b <= last)
        .filter_map(|&b| {
            let i = b - 1;
            let lo = i.saturating_sub(half as usize).max(first);
            let hi = (i + half as usize).min(last);
            let around = speeds[lo..=hi].iter().sum::<f64>() / (hi - lo + 1) as f64;
            (around > 0.0).then(|| 1.0 - speeds[i] / around)
        })
        .collect();
    let dip = if dips.is_empty() {
        0.0
    } else {
        dips.iter().sum::<f64>() / dips.len() as f64
    };

    let wobble = if span.len() >= 3 {
        let sq: f64 = span
            .windows(3)
            .map(|w| (w[2] - 2.0 * w[1] + w[0]).powi(2))
            .sum();
        rel((sq / (span.len() - 2) as f64).sqrt())
    } else {
        0.0
    };
    let settle = match speeds.last() {
        Some(&s) if peak > 0.0 => s / peak,
        _ => 0.0,
    };

    let ease_error = (iou.len() == n && n >= 2 && (iou[n - 1] - iou[0]).abs() > 1e-9).then(|| {
        let arrive = arrive.clamp(1, n);
        (0..n)
            .map(|i| {
                let progress = (iou[i] - iou[0]) / (iou[n - 1] - iou[0]);
                let u = if arrive <= 1 {
                    1.0
                } else {
                    (i as f64 / (arrive - 1) as f64).min(1.0)
                };
                (progress - u * u * (3.0 - 2.0 * u)).abs()
            })
            .fold(0.0, f64::max)
    });
    MotionMeasures {
        pulse,
        dip,
        wobble,
        settle,
        ease_error,
        frozen_frames: first.min(n),
        frames: n,
        frames_per_segment,
        first_frame: 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pulse_at_the_segment_period_is_seen_and_a_smooth_ramp_is_not() {
        let p = 6.0;
        let smooth: Vec<f64> = (0..60)
            .map(|f| (std::f64::consts::PI * f as f64 / 59.0).sin() + 0.01)
            .collect();
        let boundaries: Vec<usize> = (1..10).map(|k| 1 + 6 * k).collect();
        let m = measure(&smooth, &[], &boundaries, p, 48);
        assert!(
            m.pulse < 0.02 && m.dip.abs() < 0.02 && m.wobble < 0.05,
            "{m:?}"
        );
        let pulsing: Vec<f64> = smooth
            .iter()
            .enumerate()
            .map(|(f, s)| {
                let phase = (f as f64 / p).fract();
                s * (0.6 + 0.8 * (std::f64::consts::PI * phase).sin())
            })
            .collect();
        let m = measure(&pulsing, &[], &boundaries, p, 48);
        assert!(m.pulse > 0.2 && m.dip > 0.3 && m.wobble > 0.2, "{m:?}");
        // Frozen frames, settle and ease error.
        let mut late = vec![0.0; 10];
        late.extend(smooth.iter().skip(10).take(40));
        let iou: Vec<f64> = (0..late.len()).map(|f| f as f64 / 49.0).collect();
        let m = measure(&late, &iou, &[], p, 50);
        assert_eq!(m.frozen_frames, 10);
        assert!(m.settle > 0.5, "{m:?}");
        let e = m.ease_error.unwrap();
        // max |u - smoothstep(u)| = 0.0962 (at u = 0.211).
        assert!(
            (e - 0.0962).abs() < 0.003,
            "linear progress against a smoothstep: {e}"
        );
    }
}
