use super::*;

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

#[test]
fn a_log_axis_gives_three_decades_equal_room() {
    let c = Frame::new("t", "d", "x", "y")
        .x((0.0, 1.0), Scale::Linear)
        .y((0.001, 10.0), Scale::Log)
        .chart();
    let decade = (H - TOP - BOTTOM) / 4.0;
    assert!((c.py(0.001) - (H - BOTTOM)).abs() < 1e-9);
    assert!((c.py(0.01) - (H - BOTTOM - decade)).abs() < 1e-9);
    assert!((c.py(10.0) - TOP).abs() < 1e-9);
    // Zero and negative values sit on the axis.
    assert_eq!(c.py(0.0), H - BOTTOM);
}

#[test]
fn marks_are_read_back_with_their_extent() {
    let mut c = Frame::new("t", "set <A>", "x", "y")
        .x((0.0, 2.0), Scale::Linear)
        .y((0.001, 10.0), Scale::Log)
        .chart();
    c.bar("before", 0.0, 1.0, 3.0, COLOURS[0], 1.0);
    c.bar("after", 1.0, 2.0, 0.003, COLOURS[1], 1.0);
    c.points("after", &[(1.5, 0.01)], COLOURS[1]);
    c.legend("after", COLOURS[1]);
    let svg = c.finish();
    assert!(
        svg.contains("set &lt;A&gt;"),
        "the data set is named, escaped"
    );
    let after = series_marks(&svg, "after");
    assert_eq!(after.len(), 2);
    let decade = (H - TOP - BOTTOM) / 4.0;
    assert_eq!(after[0].value, 0.003);
    // log10(0.003 / 0.001) = 0.477 of a decade (pixels rounded to 0.1).
    assert!(
        (after[0].extent - 0.477_12 * decade).abs() < 0.2,
        "{after:?}"
    );
    assert!((after[1].extent - decade).abs() < 0.2, "{after:?}");
    // The legend is above the plot area, not on it.
    let legend = svg.split("class=\"legend\"").nth(1).unwrap_or("");
    let y: f64 = read::attr(legend, "y")
        .and_then(|v| v.parse().ok())
        .unwrap_or(1e9);
    assert!(y + 12.0 <= TOP, "legend at y {y}");
}
