//! A minimal SVG chart writer: one plot area with linear or logarithmic axes, "nice"
//! ticks, bars, lines, points, box plots, a subtitle naming the data set and a legend in
//! its own strip above the plot (never over the data). Hand-written so reports need no
//! font or image libraries.
//!
//! Every mark of a named series carries `data-series` and `data-value` attributes, so
//! tests and the browser check read what was drawn ([`series_marks`]) instead of guessing
//! from colours.

use std::fmt::Write;

mod axis;
mod read;

pub use axis::{Scale, label, log_range, log_ticks, ticks};
pub use read::{Mark, series_boxes, series_marks};

/// Series colours (colour-blind safe: Okabe-Ito).
pub const COLOURS: [&str; 4] = ["#E69F00", "#0072B2", "#009E73", "#CC79A7"];

const W: f64 = 720.0;
const H: f64 = 420.0;
const LEFT: f64 = 78.0;
const RIGHT: f64 = 20.0;
const TOP: f64 = 74.0;
const BOTTOM: f64 = 55.0;

/// Escape text for SVG and HTML (element content and quoted attribute values).
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&#39;")
}

/// What a chart shows: titles, data ranges and scales (fixed before any mark is drawn).
#[derive(Debug, Clone)]
pub struct Frame {
    /// Title (what is plotted).
    pub title: String,
    /// The data set it shows (line under the title).
    pub dataset: String,
    /// x axis label with unit.
    pub x_label: String,
    /// y axis label with unit.
    pub y_label: String,
    /// x data range.
    pub x: (f64, f64),
    /// y data range.
    pub y: (f64, f64),
    /// x axis scale.
    pub x_scale: Scale,
    /// y axis scale.
    pub y_scale: Scale,
    /// Extra room under the plot for slanted category labels (pixels).
    pub extra_bottom: f64,
}

impl Frame {
    /// A frame with linear axes.
    pub fn new(title: &str, dataset: &str, x_label: &str, y_label: &str) -> Frame {
        Frame {
            title: title.into(),
            dataset: dataset.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x: (0.0, 1.0),
            y: (0.0, 1.0),
            x_scale: Scale::Linear,
            y_scale: Scale::Linear,
            extra_bottom: 0.0,
        }
    }

    /// Set the x range and scale.
    pub fn x(mut self, range: (f64, f64), scale: Scale) -> Frame {
        self.x = range;
        self.x_scale = scale;
        self
    }

    /// Set the y range and scale.
    pub fn y(mut self, range: (f64, f64), scale: Scale) -> Frame {
        self.y = range;
        self.y_scale = scale;
        self
    }

    /// Leave `px` more pixels under the plot (slanted category labels).
    pub fn extra_bottom(mut self, px: f64) -> Frame {
        self.extra_bottom = px;
        self
    }

    /// Start drawing.
    pub fn chart(self) -> Chart {
        Chart::from_frame(self)
    }
}

fn fix_range(r: (f64, f64), scale: Scale) -> (f64, f64) {
    match scale {
        Scale::Log if !(r.0 > 0.0 && r.1 > r.0) => log_range(&[r.0, r.1]),
        Scale::Log => r,
        Scale::Linear if r.1 > r.0 => r,
        Scale::Linear => (r.0 - 0.5, r.0 + 0.5),
    }
}

/// A chart under construction: data ranges are fixed at creation.
#[derive(Debug)]
pub struct Chart {
    out: String,
    x: (f64, f64),
    y: (f64, f64),
    x_scale: Scale,
    y_scale: Scale,
    height: f64,
    legend: Vec<(String, String)>,
}

impl Chart {
    /// A chart with linear axes, title, axis labels and data ranges `x` and `y`.
    pub fn new(title: &str, x_label: &str, y_label: &str, x: (f64, f64), y: (f64, f64)) -> Chart {
        Frame::new(title, "", x_label, y_label)
            .x(x, Scale::Linear)
            .y(y, Scale::Linear)
            .chart()
    }

    fn from_frame(f: Frame) -> Chart {
        let x = fix_range(f.x, f.x_scale);
        let y = fix_range(f.y, f.y_scale);
        let h = H + f.extra_bottom.max(0.0);
        let mut out = String::new();
        let _ = write!(
            out,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{h}" viewBox="0 0 {W} {h}" font-family="sans-serif" font-size="12" data-y-scale="{}">"#,
            if f.y_scale == Scale::Log {
                "log"
            } else {
                "linear"
            }
        );
        let _ = write!(
            out,
            r##"<title>{}</title><rect width="{W}" height="{h}" fill="#ffffff"/>"##,
            escape(&f.title)
        );
        let _ = write!(
            out,
            r#"<text x="{}" y="20" text-anchor="middle" font-size="15">{}</text>"#,
            W / 2.0,
            escape(&f.title)
        );
        if !f.dataset.is_empty() {
            let _ = write!(
                out,
                r##"<text x="{}" y="38" text-anchor="middle" fill="#555" class="dataset">{}</text>"##,
                W / 2.0,
                escape(&f.dataset)
            );
        }
        let _ = write!(
            out,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            LEFT + (W - LEFT - RIGHT) / 2.0,
            h - 10.0,
            escape(&f.x_label)
        );
        let mid = TOP + (h - f.extra_bottom - TOP - BOTTOM) / 2.0;
        let _ = write!(
            out,
            r#"<text x="16" y="{mid}" text-anchor="middle" transform="rotate(-90 16 {mid})">{}</text>"#,
            escape(&f.y_label)
        );
        let mut c = Chart {
            out,
            x,
            y,
            x_scale: f.x_scale,
            y_scale: f.y_scale,
            height: h - f.extra_bottom,
            legend: vec![],
        };
        c.axes();
        c
    }

    fn frac(v: f64, r: (f64, f64), s: Scale) -> f64 {
        match s {
            Scale::Linear => (v - r.0) / (r.1 - r.0),
            Scale::Log if v > 0.0 && v.is_finite() => {
                ((v.log10() - r.0.log10()) / (r.1.log10() - r.0.log10())).max(0.0)
            }
            Scale::Log => 0.0,
        }
    }

    /// Pixel x of data x.
    pub fn px(&self, x: f64) -> f64 {
        LEFT + Self::frac(x, self.x, self.x_scale) * (W - LEFT - RIGHT)
    }

    /// Pixel y of data y.
    pub fn py(&self, y: f64) -> f64 {
        self.height - BOTTOM - Self::frac(y, self.y, self.y_scale) * (self.height - TOP - BOTTOM)
    }

    fn axis_ticks(r: (f64, f64), s: Scale, n: usize) -> Vec<f64> {
        match s {
            Scale::Linear => ticks(r.0, r.1, n),
            Scale::Log => log_ticks(r.0, r.1),
        }
    }

    fn axes(&mut self) {
        let (x0, x1, y0, y1) = (LEFT, W - RIGHT, TOP, self.height - BOTTOM);
        for t in Self::axis_ticks(self.y, self.y_scale, 6) {
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
        for t in Self::axis_ticks(self.x, self.x_scale, 8) {
            let p = self.px(t);
            self.x_label_at(p, &label(t));
        }
    }

    /// A text label under the x axis at pixel `p`.
    pub fn x_label_at(&mut self, p: f64, text: &str) {
        let y = self.height - BOTTOM;
        let _ = write!(
            self.out,
            r##"<line x1="{p:.1}" y1="{y}" x2="{p:.1}" y2="{}" stroke="#333"/><text x="{p:.1}" y="{}" text-anchor="middle">{}</text>"##,
            y + 5.0,
            y + 18.0,
            escape(text)
        );
    }

    /// A slanted category label under the x axis at pixel `p` (needs `extra_bottom`).
    pub fn x_category_at(&mut self, p: f64, text: &str) {
        let y = self.height - BOTTOM + 14.0;
        let _ = write!(
            self.out,
            r#"<text x="{p:.1}" y="{y}" text-anchor="end" font-size="11" transform="rotate(-40 {p:.1} {y})">{}</text>"#,
            escape(text)
        );
    }

    /// A bar of `series` from the bottom of the y axis to `h`, between data x `a` and `b`.
    pub fn bar(&mut self, series: &str, a: f64, b: f64, h: f64, colour: &str, opacity: f64) {
        let (pa, pb, top, base) = (self.px(a), self.px(b), self.py(h), self.py(self.y.0));
        let _ = write!(
            self.out,
            r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{colour}" fill-opacity="{opacity}" data-series="{}" data-value="{h}"/>"#,
            pa.min(pb),
            top.min(base),
            (pb - pa).abs().max(0.5),
            (base - top).abs(),
            escape(series)
        );
    }

    /// A polyline of `series` through data points.
    pub fn line(&mut self, series: &str, pts: &[(f64, f64)], colour: &str) {
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
            r#"<path d="{}" fill="none" stroke="{colour}" stroke-width="1.5" data-series="{}"/>"#,
            d.trim_end(),
            escape(series)
        );
    }

    /// Points (small circles) of `series`; `data-value` holds the y value.
    pub fn points(&mut self, series: &str, pts: &[(f64, f64)], colour: &str) {
        for (x, y) in pts {
            let _ = write!(
                self.out,
                r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{colour}" data-series="{}" data-value="{y}"/>"#,
                self.px(*x),
                self.py(*y),
                escape(series)
            );
        }
    }

    /// A box plot of `series` at data x `x` (width in data units): whiskers min/max, box
    /// q1..q3, median. The box carries `data-value` (the median) and `data-quartiles`
    /// (min q1 median q3 max), so a reader can check what was drawn.
    pub fn boxplot(&mut self, series: &str, x: f64, width: f64, q: [f64; 5], colour: &str) {
        let (a, b, m) = (
            self.px(x - width / 2.0),
            self.px(x + width / 2.0),
            self.px(x),
        );
        let [mn, q1, med, q3, mx] = q.map(|v| self.py(v));
        let _ = write!(
            self.out,
            r##"<line x1="{m:.1}" y1="{mn:.1}" x2="{m:.1}" y2="{mx:.1}" stroke="#333"/><rect x="{a:.1}" y="{q3:.1}" width="{:.1}" height="{:.1}" fill="{colour}" stroke="#333" data-series="{}" data-value="{}" data-quartiles="{} {} {} {} {}"/><line x1="{a:.1}" y1="{med:.1}" x2="{b:.1}" y2="{med:.1}" stroke="#000" stroke-width="2"/>"##,
            b - a,
            (q1 - q3).max(0.5),
            escape(series),
            q[2],
            q[0],
            q[1],
            q[2],
            q[3],
            q[4]
        );
    }

    /// Add a legend entry (drawn in the strip between the title and the plot).
    pub fn legend(&mut self, name: &str, colour: &str) {
        self.legend.push((name.into(), colour.into()));
    }

    /// The finished SVG document.
    pub fn finish(mut self) -> String {
        let mut x = LEFT;
        let y = TOP - 12.0;
        for (name, colour) in &self.legend {
            let _ = write!(
                self.out,
                r#"<g class="legend"><rect x="{x}" y="{:.1}" width="12" height="12" fill="{colour}"/><text x="{}" y="{y:.1}">{}</text></g>"#,
                y - 10.0,
                x + 17.0,
                escape(name)
            );
            x += 30.0 + 6.5 * name.chars().count() as f64;
        }
        self.out.push_str("</svg>\n");
        self.out
    }
}

#[cfg(test)]
mod tests;
