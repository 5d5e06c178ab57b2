//! PNG plots people look at: paths in the workspace and error-vector fields.
//!
//! Built on `plotters` with its pure-Rust bitmap backend and an embedded DejaVu Sans font
//! (`assets/`), so plotting needs no system library or font on the machine. Every plot is
//! written atomically (see [`super::atomic`]).

use super::atomic::write_atomic_with;
use super::IoError;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

pub(crate) fn ensure_font() {
    REGISTER.call_once(|| {
        // The font is valid and compiled in; a failure here would be a build defect.
        let _ = register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// The palette, in the order series use it.
pub const COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(127, 127, 127),
];

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    Line,
    Dots,
}

/// One named series of x-y points.
pub struct Series<'a> {
    pub label: &'a str,
    pub points: &'a [[f64; 2]],
    pub mark: Mark,
}

fn bounds<'a>(points: impl Iterator<Item = &'a [f64; 2]>) -> Option<([f64; 2], [f64; 2])> {
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in points {
        for k in 0..2 {
            if p[k].is_finite() {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
    }
    if !(lo[0] <= hi[0] && lo[1] <= hi[1]) {
        return None;
    }
    // Pad by 5 % (and never to a zero-width range).
    let pad = |k: usize| ((hi[k] - lo[k]) * 0.05).max(1e-9);
    Some(([lo[0] - pad(0), lo[1] - pad(1)], [hi[0] + pad(0), hi[1] + pad(1)]))
}

fn err(e: impl std::fmt::Display) -> IoError {
    IoError::Plot(e.to_string())
}

/// Draws the legend and writes the bitmap: how every plot ends.
fn finish<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    root: &DrawingArea<DB, plotters::coord::Shift>,
) -> Result<(), IoError> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 16))
        .draw()
        .map_err(err)?;
    root.present().map_err(err)
}

/// An x-y plot of several series (lines or dots) with a legend.
pub fn xy_plot(path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series<'_>]) -> Result<(), IoError> {
    ensure_font();
    let (lo, hi) = bounds(series.iter().flat_map(|s| s.points.iter())).ok_or_else(|| IoError::Invalid(format!("plot '{title}': no finite points")))?;
    write_atomic_with(path, |tmp| {
        let root = BitMapBackend::new(tmp, (1000, 750)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1])
            .map_err(err)?;
        chart.configure_mesh().x_desc(x_label).y_desc(y_label).label_style(("sans-serif", 15)).draw().map_err(err)?;
        for (k, s) in series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let pts = s.points.iter().filter(|p| p[0].is_finite() && p[1].is_finite()).map(|p| (p[0], p[1]));
            let drawn = match s.mark {
                Mark::Line => chart.draw_series(LineSeries::new(pts, colour.stroke_width(2))).map_err(err)?,
                Mark::Dots => chart.draw_series(pts.map(|p| Circle::new(p, 3, colour.filled()))).map_err(err)?,
            };
            drawn
                .label(s.label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(3)));
        }
        finish(&mut chart, &root)
    })
}

/// One field of error vectors: arrows from `base_mm[i]` along `error_um[i]`.
pub struct VectorField<'a> {
    pub label: &'a str,
    pub base_mm: &'a [[f64; 2]],
    pub error_um: &'a [[f64; 2]],
}

/// Error vectors over the workspace, magnified so the largest arrow is about a tenth of the
/// plot; the magnification and the largest error are printed in the caption. Several fields
/// (e.g. before and after a calibration step) share one scale so they can be compared.
pub fn vector_plot(path: &Path, title: &str, fields: &[VectorField<'_>]) -> Result<(), IoError> {
    ensure_font();
    let (lo, hi) = bounds(fields.iter().flat_map(|f| f.base_mm.iter())).ok_or_else(|| IoError::Invalid(format!("plot '{title}': no points")))?;
    let span_mm = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let max_um = fields
        .iter()
        .flat_map(|f| f.error_um.iter())
        .map(|e| e[0].hypot(e[1]))
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let mm_per_um = if max_um > 0.0 { 0.1 * span_mm / max_um } else { 0.0 };
    let caption = format!("{title} (largest {max_um:.1} µm; 1 mm of arrow = {:.1} µm)", if mm_per_um > 0.0 { 1.0 / mm_per_um } else { 0.0 });
    let pad = 0.12 * span_mm;
    let (lo, hi) = ([lo[0] - pad, lo[1] - pad], [hi[0] + pad, hi[1] + pad]);
    write_atomic_with(path, |tmp| {
        let root = BitMapBackend::new(tmp, (1000, 1000)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(&caption, ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1])
            .map_err(err)?;
        chart.configure_mesh().x_desc("x (mm)").y_desc("y (mm)").label_style(("sans-serif", 15)).draw().map_err(err)?;
        for (k, f) in fields.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let arrows = f.base_mm.iter().zip(f.error_um.iter()).filter(|(b, e)| b.iter().chain(e.iter()).all(|v| v.is_finite())).map(
                move |(b, e)| {
                    let tip = (b[0] + e[0] * mm_per_um, b[1] + e[1] * mm_per_um);
                    PathElement::new(vec![(b[0], b[1]), tip], colour.stroke_width(2))
                },
            );
            chart
                .draw_series(arrows)
                .map_err(err)?
                .label(f.label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(3)));
            chart.draw_series(f.base_mm.iter().map(|b| Circle::new((b[0], b[1]), 2, colour.filled()))).map_err(err)?;
        }
        finish(&mut chart, &root)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_files() {
        let dir = tempfile::tempdir().unwrap();
        let circle: Vec<[f64; 2]> = (0..100).map(|k| {
            let a = k as f64 * 0.0628;
            [200.0 + 20.0 * a.cos(), 20.0 * a.sin()]
        }).collect();
        let p = dir.path().join("path.png");
        xy_plot(&p, "circle", "x (mm)", "y (mm)", &[Series { label: "cmd", points: &circle, mark: Mark::Line }]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        let v = dir.path().join("vec.png");
        let errs: Vec<[f64; 2]> = circle.iter().map(|p| [p[1], -p[0] * 0.01]).collect();
        vector_plot(&v, "errors", &[VectorField { label: "before", base_mm: &circle, error_um: &errs }]).unwrap();
        assert_eq!(&std::fs::read(&v).unwrap()[1..4], b"PNG");
        assert!(xy_plot(&dir.path().join("empty.png"), "x", "x", "y", &[]).is_err());
        assert!(!dir.path().join("empty.png").exists());
    }
}
