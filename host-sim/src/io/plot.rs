//! PNG plots people look at: paths in the workspace and error-vector fields.
//!
//! Built on `plotters` with its pure-Rust bitmap backend and an embedded DejaVu Sans font
//! (`assets/`), so plotting needs no system library or font on the machine. Every plot is
//! rendered to PNG bytes in memory (`*_png`), so a command can stage it with its other outputs
//! ([`super::atomic::Outputs`]) or embed it in a report; the path-taking forms write one file
//! atomically.
//!
//! Error-vector plots are drawn to be read at a glance: **equal scales** on x and y (a circle
//! stays a circle, so directions are true), every target marked, arrows with heads, a **scale
//! arrow** of a round length (1, 2 or 5 × 10ⁿ µm) in the corner, and the summary figures the
//! caller gives printed on the plot.

use super::atomic::write_atomic;
use super::IoError;
use plotters::coord::Shift;
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
    Some((
        [lo[0] - pad(0), lo[1] - pad(1)],
        [hi[0] + pad(0), hi[1] + pad(1)],
    ))
}

pub(crate) fn err(e: impl std::fmt::Display) -> IoError {
    IoError::Plot(e.to_string())
}

pub(crate) type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Renders a `width × height` bitmap drawn by `draw` and encodes it as PNG.
pub(crate) fn render(
    width: u32,
    height: u32,
    draw: impl FnOnce(&Area<'_>) -> Result<(), IoError>,
) -> Result<Vec<u8>, IoError> {
    ensure_font();
    let mut rgb = vec![0u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        draw(&root)?;
        root.present().map_err(err)?;
    }
    let mut png_bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut png_bytes, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(err)?;
    writer.write_image_data(&rgb).map_err(err)?;
    writer.finish().map_err(err)?;
    Ok(png_bytes)
}

/// Draws the legend: how every chart ends.
pub(crate) fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> Result<(), IoError> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 16))
        .draw()
        .map_err(err)
}

/// Lines of text in a framed box at pixel `at` (top left) of `area`.
fn text_box(area: &Area<'_>, at: (i32, i32), lines: &[String]) -> Result<(), IoError> {
    if lines.is_empty() {
        return Ok(());
    }
    let font = ("sans-serif", 15).into_font();
    let style = TextStyle::from(font.clone());
    let width = lines
        .iter()
        .map(|l| area.estimate_text_size(l, &style).map_or(0, |s| s.0))
        .max()
        .unwrap_or(0) as i32;
    let h = 19;
    area.draw(&Rectangle::new(
        [at, (at.0 + width + 14, at.1 + h * lines.len() as i32 + 8)],
        WHITE.mix(0.9).filled(),
    ))
    .map_err(err)?;
    area.draw(&Rectangle::new(
        [at, (at.0 + width + 14, at.1 + h * lines.len() as i32 + 8)],
        BLACK.stroke_width(1),
    ))
    .map_err(err)?;
    for (k, l) in lines.iter().enumerate() {
        area.draw(&Text::new(
            l.clone(),
            (at.0 + 7, at.1 + 5 + h * k as i32),
            font.clone(),
        ))
        .map_err(err)?;
    }
    Ok(())
}

/// An x-y plot of several series (lines or dots) with a legend, as PNG bytes.
pub fn xy_plot_png(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
) -> Result<Vec<u8>, IoError> {
    let (lo, hi) = bounds(series.iter().flat_map(|s| s.points.iter()))
        .ok_or_else(|| IoError::Invalid(format!("plot '{title}': no finite points")))?;
    render(1000, 750, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1])
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style(("sans-serif", 15))
            .draw()
            .map_err(err)?;
        for (k, s) in series.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let pts = s
                .points
                .iter()
                .filter(|p| p[0].is_finite() && p[1].is_finite())
                .map(|p| (p[0], p[1]));
            let drawn = match s.mark {
                Mark::Line => chart
                    .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
                    .map_err(err)?,
                Mark::Dots => chart
                    .draw_series(pts.map(|p| Circle::new(p, 3, colour.filled())))
                    .map_err(err)?,
            };
            drawn.label(s.label).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(3))
            });
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)
    })
}

/// [`xy_plot_png`] written to `path`.
pub fn xy_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
) -> Result<(), IoError> {
    write_atomic(path, &xy_plot_png(title, x_label, y_label, series)?)
}

/// One field of error vectors: arrows from `base_mm[i]` along `error_um[i]`.
pub struct VectorField<'a> {
    pub label: &'a str,
    pub base_mm: &'a [[f64; 2]],
    pub error_um: &'a [[f64; 2]],
}

impl<'a> VectorField<'a> {
    /// The field `label`: arrows from `base_mm[i]` along `error_um[i]`.
    pub fn new(label: &'a str, base_mm: &'a [[f64; 2]], error_um: &'a [[f64; 2]]) -> Self {
        VectorField {
            label,
            base_mm,
            error_um,
        }
    }
}

/// 1, 2 or 5 × 10ⁿ, the largest not above `v` (> 0).
pub fn round_length(v: f64) -> f64 {
    let p = 10f64.powf(v.log10().floor());
    [5.0, 2.0, 1.0]
        .iter()
        .map(|m| m * p)
        .find(|&c| c <= v)
        .unwrap_or(p)
}

/// Half the angle between the two strokes of an arrowhead of the vector plots (rad).
const HEAD_HALF_ANGLE_RAD: f64 = 0.5;

/// An arrow from `a` to `b` (data coordinates, equal scales): the shaft and a head of two
/// strokes `head` long (data units; at most 0.4 of the arrow), each `half_angle_rad` off the
/// shaft. The vector plots' and the verification report's arrows.
pub(super) fn arrow(
    a: (f64, f64),
    b: (f64, f64),
    head: f64,
    half_angle_rad: f64,
    style: ShapeStyle,
) -> Vec<PathElement<(f64, f64)>> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len = dx.hypot(dy);
    let mut v = vec![PathElement::new(vec![a, b], style)];
    if len > 0.0 {
        let h = head.min(0.4 * len);
        let (ux, uy) = (dx / len, dy / len);
        let (c, s) = (half_angle_rad.cos(), half_angle_rad.sin());
        for sign in [1.0, -1.0] {
            let (rx, ry) = (ux * c - sign * uy * s, sign * ux * s + uy * c);
            v.push(PathElement::new(
                vec![b, (b.0 - h * rx, b.1 - h * ry)],
                style,
            ));
        }
    }
    v
}

/// Error vectors over the workspace as PNG bytes (see the module doc): equal scales, marked
/// targets, arrowheads, a scale arrow, `notes` (summary figures) in a box. The arrows are
/// magnified so the largest is about a tenth of the plot; several fields (e.g. before and after
/// a calibration step) share one magnification so they can be compared.
pub fn vector_plot_png(
    title: &str,
    fields: &[VectorField<'_>],
    notes: &[String],
) -> Result<Vec<u8>, IoError> {
    let (lo, hi) = bounds(fields.iter().flat_map(|f| f.base_mm.iter()))
        .ok_or_else(|| IoError::Invalid(format!("plot '{title}': no points")))?;
    let span_mm = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let max_um = fields
        .iter()
        .flat_map(|f| f.error_um.iter())
        .map(|e| e[0].hypot(e[1]))
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let mm_per_um = if max_um > 0.0 {
        0.1 * span_mm / max_um
    } else {
        0.0
    };
    let caption = format!("{title} (largest {max_um:.1} µm)");
    // Room for the arrows and the boxes around the points.
    let pad = 0.14 * span_mm;
    let (mut lo, mut hi) = ([lo[0] - pad, lo[1] - pad], [hi[0] + pad, hi[1] + pad]);
    // Equal scales: the plot's pixel aspect follows the data's, within bounds; the ranges are then
    // widened to the plotting area's exact aspect.
    let (w, area_w) = (1000u32, 1000.0 - 70.0 - 30.0);
    let data_aspect = (hi[1] - lo[1]) / (hi[0] - lo[0]);
    let h = (area_w * data_aspect + 45.0 + 30.0 + 45.0).clamp(600.0, 1400.0) as u32;
    render(w, h, |root| {
        let build = |lo: [f64; 2], hi: [f64; 2]| {
            ChartBuilder::on(root)
                .caption(&caption, ("sans-serif", 20))
                .margin(15)
                .x_label_area_size(45)
                .y_label_area_size(70)
                .build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1])
                .map_err(err)
        };
        let (pw, ph) = build(lo, hi)?.plotting_area().dim_in_pixel();
        let (mm_x, mm_y) = ((hi[0] - lo[0]) / pw as f64, (hi[1] - lo[1]) / ph as f64);
        let mm_per_px = mm_x.max(mm_y);
        for (k, px) in [(0, pw as f64), (1, ph as f64)] {
            let c = 0.5 * (lo[k] + hi[k]);
            lo[k] = c - 0.5 * px * mm_per_px;
            hi[k] = c + 0.5 * px * mm_per_px;
        }
        root.fill(&WHITE).map_err(err)?;
        let mut chart = build(lo, hi)?;
        chart
            .configure_mesh()
            .x_desc("x (mm)")
            .y_desc("y (mm)")
            .label_style(("sans-serif", 15))
            .draw()
            .map_err(err)?;
        let head = 0.012 * span_mm;
        for (k, f) in fields.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let style = colour.stroke_width(2);
            let arrows: Vec<PathElement<(f64, f64)>> = f
                .base_mm
                .iter()
                .zip(f.error_um.iter())
                .filter(|(b, e)| b.iter().chain(e.iter()).all(|v| v.is_finite()))
                .flat_map(|(b, e)| {
                    arrow(
                        (b[0], b[1]),
                        (b[0] + e[0] * mm_per_um, b[1] + e[1] * mm_per_um),
                        head,
                        HEAD_HALF_ANGLE_RAD,
                        style,
                    )
                })
                .collect();
            chart
                .draw_series(arrows)
                .map_err(err)?
                .label(f.label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(3))
                });
            chart
                .draw_series(
                    f.base_mm
                        .iter()
                        .map(|b| Circle::new((b[0], b[1]), 2, colour.filled())),
                )
                .map_err(err)?;
        }
        // The scale arrow, bottom right.
        if mm_per_um > 0.0 {
            let len_um = round_length(0.5 * max_um);
            let y = lo[1] + 0.04 * (hi[1] - lo[1]);
            let x1 = hi[0] - 0.04 * (hi[0] - lo[0]);
            let x0 = x1 - len_um * mm_per_um;
            chart
                .draw_series(arrow(
                    (x0, y),
                    (x1, y),
                    head,
                    HEAD_HALF_ANGLE_RAD,
                    BLACK.stroke_width(3),
                ))
                .map_err(err)?;
            chart
                .draw_series(std::iter::once(Text::new(
                    format!("{len_um} µm"),
                    (x0, y + 0.025 * (hi[1] - lo[1])),
                    ("sans-serif", 16).into_font(),
                )))
                .map_err(err)?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        text_box(root, (90, 50), notes)
    })
}

/// [`vector_plot_png`] without notes, written to `path`.
pub fn vector_plot(path: &Path, title: &str, fields: &[VectorField<'_>]) -> Result<(), IoError> {
    write_atomic(path, &vector_plot_png(title, fields, &[])?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_files() {
        let dir = tempfile::tempdir().unwrap();
        let circle: Vec<[f64; 2]> = (0..100)
            .map(|k| {
                let a = k as f64 * 0.0628;
                [200.0 + 20.0 * a.cos(), 20.0 * a.sin()]
            })
            .collect();
        let p = dir.path().join("path.png");
        xy_plot(
            &p,
            "circle",
            "x (mm)",
            "y (mm)",
            &[Series {
                label: "cmd",
                points: &circle,
                mark: Mark::Line,
            }],
        )
        .unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        let v = dir.path().join("vec.png");
        let errs: Vec<[f64; 2]> = circle.iter().map(|p| [p[1], -p[0] * 0.01]).collect();
        vector_plot(&v, "errors", &[VectorField::new("before", &circle, &errs)]).unwrap();
        assert_eq!(&std::fs::read(&v).unwrap()[1..4], b"PNG");
        assert!(xy_plot(&dir.path().join("empty.png"), "x", "x", "y", &[]).is_err());
        assert!(!dir.path().join("empty.png").exists());
        assert_eq!(
            (round_length(7.3), round_length(0.23), round_length(10.0)),
            (5.0, 0.2, 10.0)
        );
    }
}
