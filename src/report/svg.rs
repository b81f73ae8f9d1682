//! A minimal SVG chart writer: one plot area with linear axes, "nice" ticks, bars, lines,
//! box plots and a legend. Hand-written so reports need no font or image libraries.

use std::fmt::Write;

/// Series colours (colour-blind safe: Okabe-Ito).
pub const COLOURS: [&str; 4] = ["#E69F00", "#0072B2", "#009E73", "#CC79A7"];

const W: f64 = 720.0;
const H: f64 = 400.0;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 20.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 55.0;

/// Escape text for SVG.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// About `n` round tick values covering [lo, hi].
pub fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let e = raw.log10().floor() as i32;
    // Scale by dividing for negative exponents: 6 / 10 is 0.6 exactly, 6 * 0.1 is not.
    let scale = |v: f64| {
        if e < 0 {
            v / 10f64.powi(-e)
        } else {
            v * 10f64.powi(e)
        }
    };
    let m = [1.0, 2.0, 2.5, 5.0, 10.0]
        .into_iter()
        .find(|m| scale(*m) >= raw)
        .unwrap_or(10.0);
    let step = scale(m);
    let first = (lo / step).ceil();
    let mut out = Vec::new();
    let mut k = 0;
    while scale((first + k as f64) * m) <= hi + step * 1e-9 && k < 100 {
        out.push(scale((first + k as f64) * m));
        k += 1;
    }
    out
}

fn label(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.1e}")
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// A chart under construction: data ranges are fixed at creation.
#[derive(Debug)]
pub struct Chart {
    out: String,
    x: (f64, f64),
    y: (f64, f64),
    legend: Vec<(String, String)>,
}

impl Chart {
    /// A chart with title, axis labels and data ranges `x` and `y` (y starts at `y.0`).
    pub fn new(title: &str, x_label: &str, y_label: &str, x: (f64, f64), y: (f64, f64)) -> Chart {
        let y = if y.1 > y.0 { y } else { (y.0, y.0 + 1.0) };
        let x = if x.1 > x.0 { x } else { (x.0 - 0.5, x.0 + 0.5) };
        let mut out = String::new();
        let _ = write!(
            out,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="12">"#
        );
        let _ = write!(out, r##"<rect width="{W}" height="{H}" fill="#ffffff"/>"##);
        let _ = write!(
            out,
            r#"<text x="{}" y="22" text-anchor="middle" font-size="15">{}</text>"#,
            W / 2.0,
            escape(title)
        );
        let _ = write!(
            out,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            LEFT + (W - LEFT - RIGHT) / 2.0,
            H - 12.0,
            escape(x_label)
        );
        let _ = write!(
            out,
            r#"<text x="16" y="{}" text-anchor="middle" transform="rotate(-90 16 {})">{}</text>"#,
            TOP + (H - TOP - BOTTOM) / 2.0,
            TOP + (H - TOP - BOTTOM) / 2.0,
            escape(y_label)
        );
        let mut c = Chart {
            out,
            x,
            y,
            legend: vec![],
        };
        c.axes();
        c
    }

    /// Pixel x of data x.
    pub fn px(&self, x: f64) -> f64 {
        LEFT + (x - self.x.0) / (self.x.1 - self.x.0) * (W - LEFT - RIGHT)
    }

    /// Pixel y of data y.
    pub fn py(&self, y: f64) -> f64 {
        H - BOTTOM - (y - self.y.0) / (self.y.1 - self.y.0) * (H - TOP - BOTTOM)
    }

    fn axes(&mut self) {
        let (x0, x1, y0, y1) = (LEFT, W - RIGHT, TOP, H - BOTTOM);
        for t in ticks(self.y.0, self.y.1, 6) {
            let p = self.py(t);
            let _ = write!(
                self.out,
                r##"<line x1="{x0}" y1="{p:.1}" x2="{x1}" y2="{p:.1}" stroke="#e0e0e0"/><text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"##,
                x0 - 6.0,
                p + 4.0,
                label(t)
            );
        }
        let _ = write!(
            self.out,
            r##"<path d="M{x0} {y0} V{y1} H{x1}" fill="none" stroke="#333"/>"##
        );
    }

    /// Numeric x ticks.
    pub fn x_ticks(&mut self) {
        for t in ticks(self.x.0, self.x.1, 8) {
            let p = self.px(t);
            self.x_label_at(p, &label(t));
        }
    }

    /// A text label under the x axis at pixel `p`.
    pub fn x_label_at(&mut self, p: f64, text: &str) {
        let y = H - BOTTOM;
        let _ = write!(
            self.out,
            r##"<line x1="{p:.1}" y1="{y}" x2="{p:.1}" y2="{}" stroke="#333"/><text x="{p:.1}" y="{}" text-anchor="middle">{}</text>"##,
            y + 5.0,
            y + 18.0,
            escape(text)
        );
    }

    /// A bar from y = y.0 to `h` between data x `a` and `b`.
    pub fn bar(&mut self, a: f64, b: f64, h: f64, colour: &str, opacity: f64) {
        let (pa, pb, top, base) = (self.px(a), self.px(b), self.py(h), self.py(self.y.0));
        let _ = write!(
            self.out,
            r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{colour}" fill-opacity="{opacity}"/>"#,
            pa.min(pb),
            top.min(base),
            (pb - pa).abs().max(0.5),
            (base - top).abs()
        );
    }

    /// A polyline through data points.
    pub fn line(&mut self, pts: &[(f64, f64)], colour: &str) {
        if pts.is_empty() {
            return;
        }
        let mut d = String::new();
        for (i, (x, y)) in pts.iter().enumerate() {
            let _ = write!(
                d,
                "{}{:.1} {:.1} ",
                if i == 0 { "M" } else { "L" },
                self.px(*x),
                self.py(*y)
            );
        }
        let _ = write!(
            self.out,
            r#"<path d="{}" fill="none" stroke="{colour}" stroke-width="1.5"/>"#,
            d.trim_end()
        );
    }

    /// A box plot at data x `x` (width in data units): whiskers min/max, box q1..q3, median.
    pub fn boxplot(&mut self, x: f64, width: f64, q: [f64; 5], colour: &str) {
        let (a, b, m) = (
            self.px(x - width / 2.0),
            self.px(x + width / 2.0),
            self.px(x),
        );
        let [mn, q1, med, q3, mx] = q.map(|v| self.py(v));
        let _ = write!(
            self.out,
            r##"<line x1="{m:.1}" y1="{mn:.1}" x2="{m:.1}" y2="{mx:.1}" stroke="#333"/><rect x="{a:.1}" y="{q3:.1}" width="{:.1}" height="{:.1}" fill="{colour}" stroke="#333"/><line x1="{a:.1}" y1="{med:.1}" x2="{b:.1}" y2="{med:.1}" stroke="#000" stroke-width="2"/>"##,
            b - a,
            (q1 - q3).max(0.5)
        );
    }

    /// Add a legend entry.
    pub fn legend(&mut self, name: &str, colour: &str) {
        self.legend.push((name.into(), colour.into()));
    }

    /// The finished SVG document.
    pub fn finish(mut self) -> String {
        for (i, (name, colour)) in self.legend.iter().enumerate() {
            let y = TOP + 8.0 + 18.0 * i as f64;
            let x = W - RIGHT - 170.0;
            let _ = write!(
                self.out,
                r#"<rect x="{x}" y="{:.1}" width="12" height="12" fill="{colour}"/><text x="{}" y="{:.1}">{}</text>"#,
                y - 10.0,
                x + 18.0,
                y,
                escape(name)
            );
        }
        self.out.push_str("</svg>\n");
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 1.0, 5), vec![0.0, 0.2, 0.4, 0.6, 0.8, 1.0]);
        assert_eq!(ticks(0.0, 0.37, 4), vec![0.0, 0.1, 0.2, 0.3]);
        assert_eq!(ticks(3.0, 3.0, 5), vec![3.0]);
    }

    #[test]
    fn pixels_map_the_data_range_onto_the_plot_area() {
        let c = Chart::new("t", "x", "y", (0.0, 10.0), (0.0, 2.0));
        assert_eq!(c.px(0.0), LEFT);
        assert_eq!(c.px(10.0), W - RIGHT);
        assert_eq!(c.py(0.0), H - BOTTOM);
        assert_eq!(c.py(2.0), TOP);
        let svg = c.finish();
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>\n"));
    }
}
