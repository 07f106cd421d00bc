//! Charts of a sweep's results (plotters): lines of means with 95 % error bars (or, over many
//! steps, a shaded band), one line per series, written as SVG and PNG. Text uses a bundled
//! subset of DejaVu Sans (`assets/fonts/`), so no system font library is needed.

use std::path::Path;
use std::sync::OnceLock;

use anyhow::{anyhow, Context};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::rundir::render::{robot_colour, write_png};

const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-subset.ttf");
const SIZE: (u32, u32) = (720, 450);

/// One point of a line: the mean and its 95 % interval.
#[derive(Clone, Debug, PartialEq)]
pub struct Mean {
    pub x: f64,
    pub y: f64,
    pub lo: f64,
    pub hi: f64,
}

#[derive(Clone, Debug)]
pub struct Line {
    pub name: String,
    pub points: Vec<Mean>,
}

/// The x axis: numbers, or named categories drawn at 0, 1, 2, …
#[derive(Clone, Debug)]
pub enum XAxis {
    Numeric,
    Categories(Vec<String>),
}

#[derive(Clone, Debug)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x: XAxis,
    /// Plot log10 of y, labelled with y's values.
    pub log_y: bool,
    /// Draw each point (a marker and its error bar), not only the line.
    pub markers: bool,
    /// Shade each line's interval (from `lo` to `hi`) behind it: for lines of many points,
    /// where error bars would crowd.
    pub band: bool,
    pub lines: Vec<Line>,
}

fn register_font() -> anyhow::Result<()> {
    static DONE: OnceLock<Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| "the bundled font does not load".to_string())
    })
    .clone()
    .map_err(|e| anyhow!(e))
}

/// Writes `<stem>.svg` and `<stem>.png`.
pub fn draw(chart: &Chart, stem: &Path) -> anyhow::Result<()> {
    register_font()?;
    let svg = stem.with_extension("svg");
    {
        let root = SVGBackend::new(&svg, SIZE).into_drawing_area();
        render(&root, chart).map_err(|e| anyhow!("drawing {}: {e}", svg.display()))?;
        root.present()
            .map_err(|e| anyhow!("writing {}: {e}", svg.display()))?;
    }
    let mut rgb = vec![255u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, SIZE).into_drawing_area();
        render(&root, chart).map_err(|e| anyhow!("drawing {}: {e}", stem.display()))?;
        root.present()
            .map_err(|e| anyhow!("drawing {}: {e}", stem.display()))?;
    }
    write_png(&stem.with_extension("png"), SIZE.0, SIZE.1, &rgb)
        .with_context(|| format!("plot {}", stem.display()))
}

/// y as drawn (log10 on a log axis); non-positive values cannot be drawn on a log axis.
fn drawn(log: bool, y: f64) -> Option<f64> {
    match log {
        true if y > 0.0 => Some(y.log10()),
        true => None,
        false => Some(y),
    }
}

/// The drawn data's extent, padded; a single value gets a unit-wide range.
fn extent(values: impl Iterator<Item = f64>, pad: f64) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if lo > hi {
        return (0.0, 1.0);
    }
    if lo == hi {
        let half = lo.abs().max(1.0) / 2.0;
        return (lo - half, hi + half);
    }
    let span = hi - lo;
    (lo - pad * span, hi + pad * span)
}

/// A number as a short label: 1.2M, 35k, 0.25, 3.
pub fn short_number(v: f64) -> String {
    let a = v.abs();
    let (x, unit) = if a >= 1e9 {
        (v / 1e9, "G")
    } else if a >= 1e6 {
        (v / 1e6, "M")
    } else if a >= 1e4 {
        (v / 1e3, "k")
    } else {
        (v, "")
    };
    let s = if x == x.round() {
        format!("{x:.0}")
    } else if x.abs() >= 10.0 {
        format!("{x:.1}")
    } else {
        format!("{x:.2}")
    };
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    format!("{s}{unit}")
}

/// The axes' ranges of a chart: x, and y (drawn values: log10 on a log axis).
fn ranges(c: &Chart) -> ((f64, f64), (f64, f64)) {
    let log = c.log_y;
    let ys = c.lines.iter().flat_map(|l| l.points.iter()).flat_map(|p| {
        [p.lo, p.y, p.hi]
            .into_iter()
            .filter_map(move |v| drawn(log, v))
    });
    let (y0, y1) = extent(ys, 0.06);
    let (y0, y1) = if log { (y0, y1) } else { (y0.min(0.0), y1) };
    let x = match &c.x {
        XAxis::Numeric => extent(
            c.lines.iter().flat_map(|l| l.points.iter().map(|p| p.x)),
            0.04,
        ),
        XAxis::Categories(names) => (-0.5, names.len().max(1) as f64 - 0.5),
    };
    (x, (y0, y1))
}

/// A line's points as drawn: (x, y, low, high), without the ones a log axis cannot show.
fn drawn_points(line: &Line, log: bool) -> Vec<(f64, f64, f64, f64)> {
    line.points
        .iter()
        .filter_map(|p| {
            let y = drawn(log, p.y)?;
            let lo = drawn(log, p.lo).unwrap_or(y);
            let hi = drawn(log, p.hi).unwrap_or(y);
            Some((p.x, y, lo, hi))
        })
        .collect()
}

fn render<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    c: &Chart,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let log = c.log_y;
    let ((x0, x1), (y0, y1)) = ranges(c);
    let mut chart = ChartBuilder::on(root)
        .caption(&c.title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    let categories = match &c.x {
        XAxis::Categories(names) => Some(names.clone()),
        XAxis::Numeric => None,
    };
    let x_fmt = |v: &f64| x_tick(categories.as_deref(), *v);
    let y_fmt = |v: &f64| short_number(if log { 10f64.powf(*v) } else { *v });
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(c.x_label.as_str())
        .y_desc(c.y_label.as_str())
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .light_line_style(WHITE.mix(0.0));
    if let Some(names) = &categories {
        mesh.x_labels(names.len().max(1) * 2 + 1);
    }
    mesh.draw()?;
    for (i, line) in c.lines.iter().enumerate() {
        draw_line(&mut chart, c, i, line)?;
    }
    if c.lines.len() > 1 || c.lines.first().is_some_and(|l| !l.name.is_empty()) {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .draw()?;
    }
    Ok(())
}

/// The tick label at `v` of an x axis of `categories` (at whole positions only), or of numbers.
fn x_tick(categories: Option<&[String]>, v: f64) -> String {
    let Some(names) = categories else {
        return short_number(v);
    };
    let i = v.round();
    if (v - i).abs() < 1e-6 && i >= 0.0 {
        names.get(i as usize).cloned().unwrap_or_default()
    } else {
        String::new()
    }
}

/// Line `i` of chart `c`: its interval band, the line with its legend entry, and its markers.
fn draw_line<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    c: &Chart,
    i: usize,
    line: &Line,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let log = c.log_y;
    let [r, g, b] = robot_colour(i);
    let colour = RGBColor(r, g, b);
    let pts = drawn_points(line, log);
    if c.band && pts.iter().any(|&(_, _, lo, hi)| lo < hi) {
        // Along the upper edge, then back along the lower one.
        let upper = pts.iter().map(|&(x, _, _, hi)| (x, hi));
        let lower = pts.iter().rev().map(|&(x, _, lo, _)| (x, lo));
        chart.draw_series(std::iter::once(Polygon::new(
            upper.chain(lower).collect::<Vec<_>>(),
            colour.mix(0.18).filled(),
        )))?;
    }
    chart
        .draw_series(LineSeries::new(
            pts.iter().map(|&(x, y, _, _)| (x, y)),
            colour.stroke_width(if c.markers { 2 } else { 1 }),
        ))?
        .label(line.name.as_str())
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
    if c.markers {
        chart.draw_series(
            pts.iter()
                .map(|&(x, y, lo, hi)| ErrorBar::new_vertical(x, lo, y, hi, colour.filled(), 6)),
        )?;
        chart.draw_series(
            pts.iter()
                .map(|&(x, y, _, _)| Circle::new((x, y), 3, colour.filled())),
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_numbers_read_well() {
        assert_eq!(short_number(3.0), "3");
        assert_eq!(short_number(0.25), "0.25");
        assert_eq!(short_number(35_000.0), "35k");
        assert_eq!(short_number(1_250_000.0), "1.25M");
        assert_eq!(short_number(12.5), "12.5");
    }

    #[test]
    fn extents_are_padded_and_never_empty() {
        assert_eq!(extent([].into_iter(), 0.1), (0.0, 1.0));
        let (a, b) = extent([2.0, 4.0].into_iter(), 0.5);
        assert!((a - 1.0).abs() < 1e-12 && (b - 5.0).abs() < 1e-12);
        let (a, b) = extent([3.0].into_iter(), 0.0);
        assert!(a <= 3.0 && b >= 3.0 && b > a);
        assert_eq!(drawn(true, 0.0), None);
    }
}
