//! `loss.png` (loss against evaluation and against wall time, log scale) and `preview.png`
//! (a contact sheet of frames rendered as shaded point splats), drawn with the image crate.
//! Labels use a small built-in 3x5 pixel font, so no system fonts are needed on farm nodes.

use image::{Rgb, RgbImage};
use nalgebra::{Rotation3, Vector3};
use std::path::Path;

const BACKGROUND: Rgb<u8> = Rgb([250, 250, 250]);
const INK: Rgb<u8> = Rgb([40, 40, 40]);
const GRID: Rgb<u8> = Rgb([220, 220, 220]);
const SERIES: Rgb<u8> = Rgb([200, 80, 30]);

/// 3x5 glyphs, one row per entry, bit 2 = left column.
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        '0' | 'O' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' | 'S' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        'E' => [7, 4, 7, 4, 7],
        'L' => [4, 4, 4, 4, 7],
        'I' => [7, 2, 2, 2, 7],
        'T' => [7, 2, 2, 2, 2],
        'R' => [6, 5, 6, 5, 5],
        'A' => [2, 5, 7, 5, 5],
        'N' => [5, 7, 7, 7, 5],
        'C' => [7, 4, 4, 4, 7],
        'D' => [6, 5, 5, 5, 6],
        'V' => [5, 5, 5, 5, 2],
        'P' => [7, 5, 7, 4, 4],
        'F' => [7, 4, 7, 4, 4],
        'M' => [5, 7, 7, 5, 5],
        'G' => [7, 4, 5, 5, 7],
        'H' => [5, 5, 7, 5, 5],
        'K' => [5, 5, 6, 5, 5],
        'U' => [5, 5, 5, 5, 7],
        'Y' => [5, 5, 2, 2, 2],
        'W' => [5, 5, 7, 7, 5],
        'B' => [6, 5, 6, 5, 6],
        'X' => [5, 5, 2, 5, 5],
        'Z' => [7, 1, 2, 4, 7],
        'J' => [1, 1, 1, 5, 7],
        'Q' => [7, 5, 5, 7, 1],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        ':' => [0, 2, 0, 2, 0],
        '/' => [1, 1, 2, 4, 4],
        _ => [0; 5],
    }
}

/// Draws `text` with its top-left corner at (x, y), glyph pixels `scale` wide.
fn text(img: &mut RgbImage, x: i64, y: i64, s: &str, scale: i64, color: Rgb<u8>) {
    for (i, c) in s.chars().enumerate() {
        let g = glyph(c);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    for dy in 0..scale {
                        for dx in 0..scale {
                            put(
                                img,
                                x + (i as i64 * 4 + col) * scale + dx,
                                y + row as i64 * scale + dy,
                                color,
                            );
                        }
                    }
                }
            }
        }
    }
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

fn line(img: &mut RgbImage, (x0, y0): (f64, f64), (x1, y1): (f64, f64), c: Rgb<u8>) {
    let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as i64).max(1);
    for i in 0..=n {
        let t = i as f64 / n as f64;
        put(
            img,
            (x0 + t * (x1 - x0)).round() as i64,
            (y0 + t * (y1 - y0)).round() as i64,
            c,
        );
    }
}

/// Short label for a number: 3 significant digits, E notation outside [0.01, 1e4).
fn label(v: f64) -> String {
    if v != 0.0 && !(0.01..1e4).contains(&v.abs()) {
        format!("{v:.1e}").to_uppercase()
    } else if v.abs() >= 100.0 || v.fract() == 0.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.2}")
    }
}

/// One panel: each series' `(x, y)` points on a log-y axis inside the rectangle at
/// (left, top), with a legend when series are named.
fn panel(img: &mut RgbImage, left: f64, top: f64, w: f64, h: f64, series: &[Series], title: &str) {
    text(img, left as i64, top as i64 - 22, title, 3, INK);
    let finite: Vec<Vec<(f64, f64)>> = series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .copied()
                .filter(|(x, y)| x.is_finite() && y.is_finite() && *y > 0.0)
                .collect()
        })
        .collect();
    line(img, (left, top + h), (left + w, top + h), INK);
    line(img, (left, top), (left, top + h), INK);
    let all: Vec<(f64, f64)> = finite.iter().flatten().copied().collect();
    if all.is_empty() {
        return;
    }
    let xmax = all.iter().map(|p| p.0).fold(f64::MIN_POSITIVE, f64::max);
    let (lo, hi) = all
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1.log10()), b.max(p.1.log10()))
        });
    let (lo, hi) = (lo.floor(), hi.ceil().max(lo.floor() + 1.0));
    let to_px = |(x, y): (f64, f64)| {
        (
            left + w * x / xmax,
            top + h * (1.0 - (y.log10() - lo) / (hi - lo)),
        )
    };
    let mut decade = lo;
    let step = ((hi - lo) / 8.0).ceil().max(1.0);
    while decade <= hi + 1e-9 {
        let y = top + h * (1.0 - (decade - lo) / (hi - lo));
        line(img, (left + 1.0, y), (left + w, y), GRID);
        text(
            img,
            left as i64 - 62,
            y as i64 - 5,
            &label(10f64.powf(decade)),
            2,
            INK,
        );
        decade += step;
    }
    text(img, left as i64, (top + h) as i64 + 8, "0", 2, INK);
    let xl = label(xmax);
    text(
        img,
        (left + w) as i64 - 8 * xl.len() as i64,
        (top + h) as i64 + 8,
        &xl,
        2,
        INK,
    );
    for (k, (s, pts)) in series.iter().zip(&finite).enumerate() {
        for pair in pts.windows(2) {
            line(img, to_px(pair[0]), to_px(pair[1]), s.color);
        }
        if !s.name.is_empty() {
            let y = top as i64 + 8 + 16 * k as i64;
            let x = (left + w) as i64 - 8 * s.name.len() as i64 - 30;
            line(
                img,
                (x as f64, y as f64 + 5.0),
                (x as f64 + 20.0, y as f64 + 5.0),
                s.color,
            );
            line(
                img,
                (x as f64, y as f64 + 6.0),
                (x as f64 + 20.0, y as f64 + 6.0),
                s.color,
            );
            text(img, x + 26, y, &s.name, 2, s.color);
        }
    }
}

/// A named, coloured line of points.
pub struct Series {
    pub name: String,
    pub color: Rgb<u8>,
    pub points: Vec<(f64, f64)>,
}

/// Colours for up to four series.
pub const PALETTE: [Rgb<u8>; 4] = [
    Rgb([120, 120, 120]),
    Rgb([40, 100, 200]),
    Rgb([200, 80, 30]),
    Rgb([40, 150, 60]),
];

/// Two log-y panels side by side, each with its own series.
pub fn write_two_panels(
    path: &Path,
    left: (&str, &[Series]),
    right: (&str, &[Series]),
) -> std::io::Result<()> {
    let mut img = RgbImage::from_pixel(1000, 420, BACKGROUND);
    panel(&mut img, 80.0, 50.0, 380.0, 310.0, left.1, left.0);
    panel(&mut img, 580.0, 50.0, 380.0, 310.0, right.1, right.0);
    save(path, &img)
}

/// `loss.png`: loss per evaluation (left) and against wall seconds (right).
pub fn write_loss_plot(path: &Path, losses: &[(f64, f64)]) -> std::io::Result<()> {
    let one = |points: Vec<(f64, f64)>| Series {
        name: String::new(),
        color: SERIES,
        points,
    };
    let by_index = one(losses
        .iter()
        .enumerate()
        .map(|(i, p)| (i as f64, p.1))
        .collect());
    let by_time = one(losses.to_vec());
    write_two_panels(
        path,
        ("LOSS VS ITERATION", &[by_index]),
        ("LOSS VS SECONDS", &[by_time]),
    )
}

fn save(path: &Path, img: &RgbImage) -> std::io::Result<()> {
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(std::io::Error::other)?;
    super::write_atomically(path, |w| std::io::Write::write_all(w, &bytes))
}

/// Side of a rendered frame's square tile, pixels.
const TILE: u32 = 260;

/// Each frame rendered as a `TILE`-square tile with a label, all at one scale: every particle
/// a small lit sphere (orthographic view from the front-right, slightly above; y up).
fn render_tiles(frames: &[(usize, Vec<Vector3<f64>>)], particle_radius: f64) -> Vec<RgbImage> {
    let view =
        Rotation3::from_euler_angles(0.35, 0.0, 0.0) * Rotation3::from_euler_angles(0.0, -0.6, 0.0);
    let projected: Vec<Vec<Vector3<f64>>> = frames
        .iter()
        .map(|(_, x)| x.iter().map(|p| view * p).collect())
        .collect();
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in projected.iter().flatten() {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let span = (hi - lo).x.max((hi - lo).y).max(1e-12);
    let scale = (TILE as f64 - 20.0) / span;
    let r_px = (particle_radius * scale).max(1.0);
    let light = Vector3::new(-0.4, 0.6, 0.7).normalize();
    frames
        .iter()
        .zip(&projected)
        .map(|((index, _), pts)| {
            let mut img = RgbImage::from_pixel(TILE, TILE + 24, Rgb([30, 32, 36]));
            let mut depth = vec![f64::NEG_INFINITY; (TILE * TILE) as usize];
            for p in pts {
                let cx =
                    10.0 + (p.x - lo.x) * scale + 0.5 * (TILE as f64 - 20.0 - (hi - lo).x * scale);
                let cy =
                    10.0 + (hi.y - p.y) * scale + 0.5 * (TILE as f64 - 20.0 - (hi - lo).y * scale);
                let r = r_px.ceil() as i64;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (u, v) = (dx as f64 / r_px, dy as f64 / r_px);
                        let d2 = u * u + v * v;
                        if d2 > 1.0 {
                            continue;
                        }
                        let (px, py) = (cx.round() as i64 + dx, cy.round() as i64 + dy);
                        if px < 0 || py < 0 || px >= TILE as i64 || py >= TILE as i64 {
                            continue;
                        }
                        let nz = (1.0 - d2).sqrt();
                        let z = p.z + nz * particle_radius;
                        let k = (py * TILE as i64 + px) as usize;
                        if z > depth[k] {
                            depth[k] = z;
                            let n = Vector3::new(u, -v, nz);
                            let shade = 0.25 + 0.75 * n.dot(&light).max(0.0);
                            img.put_pixel(
                                px as u32,
                                py as u32,
                                Rgb([
                                    (235.0 * shade) as u8,
                                    (150.0 * shade) as u8,
                                    (70.0 * shade) as u8,
                                ]),
                            );
                        }
                    }
                }
            }
            text(
                &mut img,
                8,
                TILE as i64 + 4,
                &format!("F {index}"),
                3,
                Rgb([220, 220, 220]),
            );
            img
        })
        .collect()
}

/// `preview.png`: the given frames side by side (see `render_tiles`).
pub fn write_preview(
    path: &Path,
    frames: &[(usize, Vec<Vector3<f64>>)],
    particle_radius: f64,
) -> std::io::Result<()> {
    let tiles = render_tiles(frames, particle_radius);
    let mut img = RgbImage::from_pixel(
        TILE * tiles.len().max(1) as u32,
        TILE + 24,
        Rgb([30, 32, 36]),
    );
    for (i, tile) in tiles.iter().enumerate() {
        image::imageops::replace(&mut img, tile, i as i64 * TILE as i64, 0);
    }
    save(path, &img)
}

/// `preview.gif`: the frames as an animation at `fps` (looping), rendered as in
/// [`write_preview`].
pub fn write_preview_gif(
    path: &Path,
    frames: &[(usize, Vec<Vector3<f64>>)],
    particle_radius: f64,
    fps: f64,
) -> std::io::Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    let tiles = render_tiles(frames, particle_radius);
    let delay =
        image::Delay::from_saturating_duration(std::time::Duration::from_secs_f64(1.0 / fps));
    let mut bytes = Vec::new();
    {
        let mut encoder = GifEncoder::new_with_speed(&mut bytes, 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(std::io::Error::other)?;
        for tile in tiles {
            let rgba = image::DynamicImage::ImageRgb8(tile).to_rgba8();
            encoder
                .encode_frame(image::Frame::from_parts(rgba, 0, 0, delay))
                .map_err(std::io::Error::other)?;
        }
    }
    super::write_atomically(path, |w| std::io::Write::write_all(w, &bytes))
}

/// `study.png`: one dot per configuration, the judge's IoU with the target (y, linear from 0
/// to the best) against wall seconds (x, log scale), the Pareto front (`true` entries) ringed
/// and joined.
pub fn write_front_plot(path: &Path, points: &[(f64, f64, bool)]) -> std::io::Result<()> {
    let (w, h, left, top) = (700.0, 420.0, 90.0, 50.0);
    let mut img = RgbImage::from_pixel(820, 540, BACKGROUND);
    text(
        &mut img,
        left as i64,
        top as i64 - 26,
        "IOU WITH TARGET VS WALL SECONDS",
        3,
        INK,
    );
    line(&mut img, (left, top + h), (left + w, top + h), INK);
    line(&mut img, (left, top), (left, top + h), INK);
    let ok: Vec<(f64, f64, bool)> = points
        .iter()
        .copied()
        .filter(|(t, q, _)| t.is_finite() && *t > 0.0 && q.is_finite())
        .collect();
    if !ok.is_empty() {
        let lo = ok
            .iter()
            .map(|p| p.0.log10())
            .fold(f64::INFINITY, f64::min)
            .floor();
        let hi = ok
            .iter()
            .map(|p| p.0.log10())
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil()
            .max(lo + 1.0);
        // The y axis spans the data, in tenths.
        let qmax = ok.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        let qmin = ok.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        let qtop = (qmax * 10.0).ceil() / 10.0;
        let qbot = ((qmin * 10.0).floor() / 10.0).min(qtop - 0.1);
        let py = |q: f64| top + h * (1.0 - (q - qbot) / (qtop - qbot));
        let px = |t: f64, q: f64| (left + w * (t.log10() - lo) / (hi - lo), py(q));
        let mut decade = lo;
        while decade <= hi + 1e-9 {
            let x = left + w * (decade - lo) / (hi - lo);
            line(&mut img, (x, top), (x, top + h - 1.0), GRID);
            let l = label(10f64.powf(decade));
            text(
                &mut img,
                x as i64 - 4 * l.len() as i64,
                (top + h) as i64 + 8,
                &l,
                2,
                INK,
            );
            decade += 1.0;
        }
        for k in 0..=5 {
            let q = qbot + (qtop - qbot) * k as f64 / 5.0;
            let y = py(q);
            line(&mut img, (left + 1.0, y), (left + w, y), GRID);
            text(&mut img, left as i64 - 50, y as i64 - 5, &label(q), 2, INK);
        }
        text(
            &mut img,
            (left + w) as i64 - 60,
            (top + h) as i64 + 28,
            "SECONDS",
            2,
            INK,
        );
        let mut front: Vec<(f64, f64)> = ok.iter().filter(|p| p.2).map(|p| px(p.0, p.1)).collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        for pair in front.windows(2) {
            line(&mut img, pair[0], pair[1], PALETTE[2]);
        }
        for &(t, q, on_front) in &ok {
            let (x, y) = px(t, q);
            let color = if on_front { PALETTE[2] } else { PALETTE[1] };
            for dx in -3i64..=3 {
                for dy in -3i64..=3 {
                    let r2 = dx * dx + dy * dy;
                    if r2 <= 9 && (!on_front || r2 >= 4 || r2 <= 1) {
                        put(&mut img, x as i64 + dx, y as i64 + dy, color);
                    }
                }
            }
        }
    }
    save(path, &img)
}
