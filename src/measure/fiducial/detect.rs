//! Markers found in a wide-field image: a two-class threshold, 4-connected components of
//! the bright pixels of a marker's area, the orientation from the gradients (modulo a
//! quarter turn), centre and angle from line fits to the four outer edges (edge positions
//! from the area under profiles across them), and the cells read and decoded (the bright
//! inner corner fixes the quarter turn).

use std::f64::consts::{FRAC_PI_2, PI};

use super::{BITS, FiducialError, GRID, MarkerPose, id_of};
use crate::measure::pattern::GrayImage;

/// The scale of the image and the markers' size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectSpec {
    /// Side of one cell (um).
    pub cell_um: f64,
    /// Pixel size (um).
    pub pixel_um: f64,
    /// Image frame position of pixel (0, 0)'s centre (um).
    pub origin_um: [f64; 2],
}

/// Bright cells of every marker (16 of the ring, the corner, two code bits).
const BRIGHT_CELLS: f64 = 19.0;

/// Every readable marker in `img`, by id.
pub fn detect(img: &GrayImage, spec: &DetectSpec) -> Result<Vec<MarkerPose>, FiducialError> {
    let cell_px = spec.cell_um / spec.pixel_um;
    if !(cell_px >= 3.0) || !cell_px.is_finite() {
        return Err(FiducialError::Setup(format!(
            "a cell is {cell_px:.2} px: at least 3 are needed (cell_um / pixel_um)"
        )));
    }
    if img.pixels.len() != img.width * img.height || img.width < 3 || img.height < 3 {
        return Err(FiducialError::Setup(
            "pixel count does not match the size".into(),
        ));
    }
    let t = threshold(img);
    let area = BRIGHT_CELLS * cell_px * cell_px;
    let mut found = Vec::new();
    let mut seen = vec![false; img.pixels.len()];
    let mut rejected = 0usize;
    for start in 0..img.pixels.len() {
        if seen[start] || f64::from(img.pixels[start]) <= t {
            continue;
        }
        let comp = component(img, t, start, &mut seen);
        let n = comp.len() as f64;
        if n < 0.5 * area || n > 1.5 * area {
            rejected += usize::from(n > 0.1 * area);
            continue;
        }
        match marker(img, t, &comp, cell_px) {
            Some((id, [x, y], theta)) => found.push(MarkerPose {
                id,
                x_um: spec.origin_um[0] + x * spec.pixel_um,
                y_um: spec.origin_um[1] + y * spec.pixel_um,
                theta_rad: theta,
            }),
            None => rejected += 1,
        }
    }
    if found.is_empty() {
        return Err(FiducialError::NotFound(format!(
            "no readable marker ({rejected} marker-sized blobs could not be read)"
        )));
    }
    found.sort_by_key(|m| m.id);
    Ok(found)
}

/// The two-class threshold (iterated midpoint of the class means) over every 7th pixel.
fn threshold(img: &GrayImage) -> f64 {
    let v: Vec<f64> = img
        .pixels
        .iter()
        .step_by(7)
        .map(|&p| f64::from(p))
        .collect();
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let mut t = (lo + hi) / 2.0;
    for _ in 0..30 {
        let (mut s0, mut n0, mut s1, mut n1) = (0.0, 0.0, 0.0, 0.0);
        for &x in &v {
            if x > t {
                s1 += x;
                n1 += 1.0;
            } else {
                s0 += x;
                n0 += 1.0;
            }
        }
        if n0 == 0.0 || n1 == 0.0 {
            break;
        }
        t = (s0 / n0 + s1 / n1) / 2.0;
    }
    t
}

/// The 4-connected bright pixels reached from `start`.
fn component(img: &GrayImage, t: f64, start: usize, seen: &mut [bool]) -> Vec<usize> {
    let w = img.width;
    let mut out = Vec::new();
    let mut stack = vec![start];
    seen[start] = true;
    while let Some(i) = stack.pop() {
        out.push(i);
        let (c, r) = (i % w, i / w);
        let mut visit = |j: usize| {
            if !seen[j] && f64::from(img.pixels[j]) > t {
                seen[j] = true;
                stack.push(j);
            }
        };
        if c > 0 {
            visit(i - 1);
        }
        if c + 1 < w {
            visit(i + 1);
        }
        if r > 0 {
            visit(i - w);
        }
        if r + 1 < img.height {
            visit(i + w);
        }
    }
    out
}

/// Bilinear sample at (x, y) px; `None` outside.
fn sample(img: &GrayImage, x: f64, y: f64) -> Option<f64> {
    if !(x >= 0.0 && y >= 0.0 && x <= (img.width - 1) as f64 && y <= (img.height - 1) as f64) {
        return None;
    }
    let (x0, y0) = (
        (x as usize).min(img.width - 2),
        (y as usize).min(img.height - 2),
    );
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let p = |c: usize, r: usize| f64::from(img.pixels[r * img.width + c]);
    Some(
        (1.0 - fy) * ((1.0 - fx) * p(x0, y0) + fx * p(x0 + 1, y0))
            + fy * ((1.0 - fx) * p(x0, y0 + 1) + fx * p(x0 + 1, y0 + 1)),
    )
}

/// One component read as a marker: id, centre (px) and angle.
fn marker(img: &GrayImage, t: f64, comp: &[usize], cell_px: f64) -> Option<(u8, [f64; 2], f64)> {
    let w = img.width;
    let xy = |i: usize| ((i % w) as f64, (i / w) as f64);
    let n = comp.len() as f64;
    let (cx, cy) = comp.iter().fold((0.0, 0.0), |(a, b), &i| {
        let (x, y) = xy(i);
        (a + x / n, b + y / n)
    });
    let side = cell_px * GRID as f64;
    let h = (0.75 * side).ceil() as i64 + 3;
    let window = |c: [f64; 2]| {
        let (x0, y0) = (c[0].round() as i64, c[1].round() as i64);
        (y0 - h..=y0 + h).flat_map(move |r| (x0 - h..=x0 + h).map(move |c| (c, r)))
    };
    let inside = |c: i64, r: i64| c >= 1 && r >= 1 && c + 1 < w as i64 && r + 1 < img.height as i64;
    let px = |c: i64, r: i64| f64::from(img.pixels[r as usize * w + c as usize]);
    // Ground and bright levels, and the orientation modulo a quarter turn from the
    // gradients (fourfold angle, weighted by the squared gradient).
    let (mut g, mut ng, mut b, mut nb, mut zc, mut zs) = (0.0, 0.0f64, 0.0, 0.0f64, 0.0, 0.0);
    for (c, r) in window([cx, cy]) {
        if !inside(c, r) {
            return None;
        }
        let v = px(c, r);
        if v > t {
            b += v;
            nb += 1.0;
        } else {
            g += v;
            ng += 1.0;
        }
        let gx = (px(c + 1, r) - px(c - 1, r)) / 2.0;
        let gy = (px(c, r + 1) - px(c, r - 1)) / 2.0;
        let m2 = gx * gx + gy * gy;
        let a = 4.0 * gy.atan2(gx);
        zc += m2 * a.cos();
        zs += m2 * a.sin();
    }
    let (g, b) = (g / ng.max(1.0), b / nb.max(1.0));
    let level = (g + b) / 2.0;
    let theta0 = zs.atan2(zc) / 4.0;
    // The centre from the extent along the marker's axes.
    let (s0, c0) = theta0.sin_cos();
    let (mut umin, mut umax, mut vmin, mut vmax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &i in comp {
        let (x, y) = xy(i);
        let (u, v) = (
            c0 * (x - cx) + s0 * (y - cy),
            -s0 * (x - cx) + c0 * (y - cy),
        );
        umin = umin.min(u);
        umax = umax.max(u);
        vmin = vmin.min(v);
        vmax = vmax.max(v);
    }
    let (uc, vc) = ((umin + umax) / 2.0, (vmin + vmax) / 2.0);
    let mut centre = [cx + c0 * uc - s0 * vc, cy + s0 * uc + c0 * vc];
    // The edges twice: the second pass profiles square to the refined edges.
    let mut theta0 = theta0;
    for _ in 0..2 {
        let (dt, [du, dv]) = edges(img, centre, theta0, side, g, b)?;
        let (s, c) = theta0.sin_cos();
        centre = [centre[0] + c * du - s * dv, centre[1] + s * du + c * dv];
        theta0 += dt;
    }
    let (s0, c0) = theta0.sin_cos();
    // The cells along the axes of theta0: grid[row][column], offsets from the centre.
    let at = |a: i64, bb: i64| {
        let (du, dv) = (a as f64 * cell_px, bb as f64 * cell_px);
        sample(
            img,
            centre[0] + c0 * du - s0 * dv,
            centre[1] + s0 * du + c0 * dv,
        )
        .map(|v| v > level)
    };
    let mut ring_bright = 0;
    for k in -2..=2i64 {
        for (a, bb) in [(k, -2), (k, 2), (-2, k), (2, k)] {
            ring_bright += usize::from(at(a, bb)?);
        }
    }
    // 20 ring samples (corners twice): a marker's are all bright.
    if ring_bright < 19 {
        return None;
    }
    // The bright inner corner: (-1, -1) turned by q quarter turns.
    let rot = |q: usize, a: i64, bb: i64| (0..q).fold((a, bb), |(x, y), _| (-y, x));
    let mut turn = None;
    for q in 0..4 {
        let (a, bb) = rot(q, -1, -1);
        if at(a, bb)? {
            if turn.is_some() {
                return None;
            }
            turn = Some(q);
        }
    }
    let q = turn?;
    let mut bits = 0u8;
    for (k, &(col, row)) in BITS.iter().enumerate() {
        let (a, bb) = rot(q, col as i64 - 2, row as i64 - 2);
        bits |= u8::from(at(a, bb)?) << k;
    }
    let id = id_of(bits)?;
    let theta = theta0 + q as f64 * FRAC_PI_2;
    let theta = theta - 2.0 * PI * ((theta + PI) / (2.0 * PI)).floor();
    Some((id, centre, theta))
}

/// The outer square's four edges, each a line fitted to edge positions measured every pixel
/// along its middle 80 %: the area under the profile across the edge (from the middle of
/// the ring to 3 px beyond, ground subtracted, over bright minus ground), which is unbiased
/// for pixels that average the light they receive. Returns the angle correction (rad) and
/// the centre's offset along the marker's two axes (px).
fn edges(
    img: &GrayImage,
    centre: [f64; 2],
    theta: f64,
    side: f64,
    g: f64,
    b: f64,
) -> Option<(f64, [f64; 2])> {
    const STEP: f64 = 0.25;
    let cell = side / GRID as f64;
    let (d0, d1) = (side / 2.0 - cell / 2.0, side / 2.0 + 3.0);
    let mut delta = 0.0;
    let mut offset = [0.0; 4];
    for (j, off) in offset.iter_mut().enumerate() {
        let phi = theta + j as f64 * FRAC_PI_2;
        let (n, tg) = ([phi.cos(), phi.sin()], [-phi.sin(), phi.cos()]);
        let (mut st, mut sd, mut stt, mut std_, mut k) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut tau = -0.4 * side;
        while tau <= 0.4 * side {
            let base = [centre[0] + tg[0] * tau, centre[1] + tg[1] * tau];
            let mut area = 0.0;
            let mut d = d0;
            while d < d1 - 1e-9 {
                // Trapezoids of the bilinear profile.
                let v0 = sample(img, base[0] + n[0] * d, base[1] + n[1] * d)?;
                let e = d + STEP;
                let v1 = sample(img, base[0] + n[0] * e, base[1] + n[1] * e)?;
                area += ((v0 + v1) / 2.0 - g) / (b - g) * STEP;
                d = e;
            }
            let edge = d0 + area;
            st += tau;
            sd += edge;
            stt += tau * tau;
            std_ += tau * edge;
            k += 1.0;
            tau += 1.0;
        }
        if k < 5.0 {
            return None;
        }
        let slope = (k * std_ - st * sd) / (k * stt - st * st);
        delta += -slope.atan();
        *off = (sd - slope * st) / k;
    }
    Some((
        delta / 4.0,
        [(offset[0] - offset[2]) / 2.0, (offset[1] - offset[3]) / 2.0],
    ))
}
