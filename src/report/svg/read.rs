//! Reading drawn marks back from an SVG the chart writer produced (tests and checks).

use super::{BOTTOM, H, escape};

/// One drawn mark of a series, as read back from an SVG: its `data-value` and its pixel
/// extent (bar height, or the distance of a point above the plot's bottom edge).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mark {
    /// The data value the mark stands for.
    pub value: f64,
    /// Its visible extent in pixels.
    pub extent: f64,
}

pub(super) fn attr(tag: &str, name: &str) -> Option<String> {
    let key = format!(" {name}=\"");
    let start = tag.find(&key)? + key.len();
    let len = tag[start..].find('"')?;
    Some(tag[start..start + len].to_string())
}

/// The bars (`<rect>`) and points (`<circle>`) of `series` in an SVG this module wrote:
/// what the tests and checks assert visibility on.
pub fn series_marks(svg: &str, series: &str) -> Vec<Mark> {
    let want = format!("data-series=\"{}\"", escape(series));
    let bottom = attr(svg.split('>').next().unwrap_or(""), "height")
        .and_then(|h| h.parse::<f64>().ok())
        .unwrap_or(H)
        - BOTTOM;
    let mut out = Vec::new();
    for tag in svg.split('<').filter(|t| t.contains(&want)) {
        let num = |n: &str| attr(tag, n).and_then(|v| v.parse::<f64>().ok());
        let Some(value) = num("data-value") else {
            continue;
        };
        let extent = if tag.starts_with("rect") {
            num("height")
        } else if tag.starts_with("circle") {
            num("cy").map(|cy| bottom - cy)
        } else {
            None
        };
        if let Some(extent) = extent {
            out.push(Mark { value, extent });
        }
    }
    out
}

/// The box plots of `series` in an SVG this module wrote: the five numbers (min, q1,
/// median, q3, max) each box was drawn from, in drawing order.
pub fn series_boxes(svg: &str, series: &str) -> Vec<[f64; 5]> {
    let want = format!("data-series=\"{}\"", escape(series));
    svg.split('<')
        .filter(|t| t.starts_with("rect") && t.contains(&want))
        .filter_map(|t| {
            let q: Vec<f64> = attr(t, "data-quartiles")?
                .split(' ')
                .filter_map(|v| v.parse().ok())
                .collect();
            <[f64; 5]>::try_from(q).ok()
        })
        .collect()
}
