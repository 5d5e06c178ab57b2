//! The accuracy report's plots (`host-sim verify`), drawn in memory as PNG bytes so the report
//! embeds them and nothing is written before everything is ready:
//!
//! * [`error_map_png`]: the 2-D error vectors of the verification targets over the workspace,
//!   with **equal axis scales** (a millimetre is as long across as up: the plot's range is
//!   widened along one axis until it is), an arrowhead on every arrow, every target marked, a
//!   scale arrow of a round length in µm, the workspace outline, and the summary figures written
//!   on the image;
//! * [`deviation_chart_png`]: the ISO 230-2 chart of one axis line: positional deviation
//!   against target position, the mean lines x̄↑, x̄↓, x̄ = (x̄↑ + x̄↓)/2, the ±2s bands
//!   x̄↑ ± 2s↑ and x̄↓ ± 2s↓ (what A is taken over), every target marked, one panel per
//!   calibration state side by side (each with its own deviation scale: before and after differ
//!   by orders of magnitude), the figures under each panel.
//!
//! `plotters` draws into an RGB buffer (its bitmap backend), the `png` crate (already under
//! `plotters`' encoder) encodes it; the font is the embedded one of [`super::plot`].

use super::plot::{arrow, ensure_font, COLOURS};
use super::IoError;
use plotters::coord::Shift;
use plotters::prelude::*;

fn err(e: impl std::fmt::Display) -> IoError {
    IoError::Plot(e.to_string())
}

/// An RGB buffer as PNG bytes.
fn encode_png(rgb: &[u8], (w, h): (u32, u32)) -> Result<Vec<u8>, IoError> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        // Line art: the best compression keeps the embedded report small (~4x smaller than
        // the default) at a few ms per plot.
        enc.set_compression(png::Compression::Best);
        let mut writer = enc.write_header().map_err(err)?;
        writer.write_image_data(rgb).map_err(err)?;
        // Finish explicitly: dropping the writer would swallow a failure.
        writer.finish().map_err(err)?;
    }
    Ok(out)
}

/// Draws `draw` on a white `size` canvas and returns the PNG bytes.
fn render<T>(
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<T, IoError>,
) -> Result<(Vec<u8>, T), IoError> {
    ensure_font();
    let mut rgb = vec![255u8; size.0 as usize * size.1 as usize * 3];
    let out = {
        let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let out = draw(&root)?;
        root.present().map_err(err)?;
        out
    };
    Ok((encode_png(&rgb, size)?, out))
}

/// Writes `lines` top-left in `area` (the title bold-sized, the rest smaller).
fn text_band(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    lines: &[String],
) -> Result<(), IoError> {
    area.draw(&Text::new(
        title.to_string(),
        (15, 8),
        ("sans-serif", 22).into_font().color(&BLACK),
    ))
    .map_err(err)?;
    for (k, l) in lines.iter().enumerate() {
        area.draw(&Text::new(
            l.clone(),
            (15, 38 + 21 * k as i32),
            ("sans-serif", 17).into_font().color(&BLACK),
        ))
        .map_err(err)?;
    }
    Ok(())
}

/// The largest 1, 2 or 5 × 10ᵏ not above `v` (> 0).
pub fn round_length_below(v: f64) -> f64 {
    let p = 10f64.powf(v.log10().floor());
    [5.0, 2.0, 1.0]
        .iter()
        .map(|m| m * p)
        .find(|&c| c <= v * (1.0 + 1e-12))
        .unwrap_or(p)
}

/// What the map shows (module doc).
pub struct ErrorMap<'a> {
    pub title: &'a str,
    /// Lines written under the title (the summary figures).
    pub summary: &'a [String],
    pub targets_mm: &'a [[f64; 2]],
    /// measured − target at each target (µm).
    pub error_um: &'a [[f64; 2]],
    /// The workspace's outline, drawn closed.
    pub outline_mm: &'a [[f64; 2]],
    /// Arrow colour (index into the palette).
    pub colour: usize,
}

/// The map's scales, as drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapScale {
    /// Millimetres of workspace per pixel along x and along y (equal: the axes' scales).
    pub mm_per_px: [f64; 2],
    /// Millimetres of arrow per µm of error (the magnification).
    pub arrow_mm_per_um: f64,
    /// The scale arrow's length (µm); 0 without errors.
    pub scale_arrow_um: f64,
}

/// Widens `lo..hi` about its centre along one axis so that a `px` plot area has the same
/// millimetres per pixel along both.
fn equal_scale(lo: [f64; 2], hi: [f64; 2], px: (u32, u32)) -> ([f64; 2], [f64; 2]) {
    let (w, h) = (f64::from(px.0.max(1)), f64::from(px.1.max(1)));
    let s = ((hi[0] - lo[0]) / w).max((hi[1] - lo[1]) / h);
    let c = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    (
        [c[0] - 0.5 * s * w, c[1] - 0.5 * s * h],
        [c[0] + 0.5 * s * w, c[1] + 0.5 * s * h],
    )
}

/// Half the angle between the two strokes of the error map's arrowheads (rad).
const HEAD_HALF_ANGLE_RAD: f64 = 0.42;

const MAP_WIDTH_PX: u32 = 900;
const MAP_BAND_PX: u32 = 100;
const MAP_MARGIN_PX: u32 = 20;
const MAP_X_LABEL_PX: u32 = 45;
const MAP_Y_LABEL_PX: u32 = 70;
/// The longest arrow, as a share of the larger side of the targets' extent.
const MAP_ARROW_SHARE: f64 = 0.07;

/// The error-vector map (module doc) as PNG bytes, and its scales.
pub fn error_map_png(map: &ErrorMap<'_>) -> Result<(Vec<u8>, MapScale), IoError> {
    if map.targets_mm.len() != map.error_um.len() {
        return Err(IoError::Invalid(format!(
            "map '{}': {} targets, {} errors",
            map.title,
            map.targets_mm.len(),
            map.error_um.len()
        )));
    }
    let finite = |p: &[f64; 2]| p.iter().all(|v| v.is_finite());
    if !map
        .targets_mm
        .iter()
        .chain(map.error_um)
        .chain(map.outline_mm)
        .all(finite)
        || map.targets_mm.is_empty()
    {
        return Err(IoError::Invalid(format!(
            "map '{}': no targets, or a coordinate that is not finite",
            map.title
        )));
    }
    let pts = map.targets_mm.iter().chain(map.outline_mm);
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in pts {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let span = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-3);
    let pad = 0.1 * span;
    let (lo, hi) = ([lo[0] - pad, lo[1] - pad], [hi[0] + pad, hi[1] + pad]);
    let max_um = map
        .error_um
        .iter()
        .map(|e| e[0].hypot(e[1]))
        .fold(0.0, f64::max);
    let mm_per_um = if max_um > 0.0 {
        MAP_ARROW_SHARE * span / max_um
    } else {
        0.0
    };
    let scale_um = if max_um > 0.0 {
        round_length_below(0.6 * max_um)
    } else {
        0.0
    };
    // Canvas height from the extent's aspect (the equal-scale widening then corrects the rest).
    let plot_w = MAP_WIDTH_PX - 2 * MAP_MARGIN_PX - MAP_Y_LABEL_PX;
    let plot_h =
        (f64::from(plot_w) * (hi[1] - lo[1]) / (hi[0] - lo[0])).clamp(400.0, 1100.0) as u32;
    let size = (
        MAP_WIDTH_PX,
        plot_h + MAP_BAND_PX + 2 * MAP_MARGIN_PX + MAP_X_LABEL_PX,
    );
    let (png, scale) = render(size, |root| {
        let (band, body) = root.split_vertically(MAP_BAND_PX);
        text_band(&band, map.title, map.summary)?;
        let builder = |lo: [f64; 2], hi: [f64; 2]| {
            ChartBuilder::on(&body)
                .margin(MAP_MARGIN_PX)
                .x_label_area_size(MAP_X_LABEL_PX)
                .y_label_area_size(MAP_Y_LABEL_PX)
                .build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1])
                .map_err(err)
        };
        let px = builder(lo, hi)?.plotting_area().dim_in_pixel();
        let (lo, hi) = equal_scale(lo, hi, px);
        let mut chart = builder(lo, hi)?;
        chart
            .configure_mesh()
            .x_desc("x (mm)")
            .y_desc("y (mm)")
            .label_style(("sans-serif", 15))
            .light_line_style(WHITE.mix(0.0))
            .draw()
            .map_err(err)?;
        let drawn_px = chart.plotting_area().dim_in_pixel();
        let mm_per_px = [
            (hi[0] - lo[0]) / f64::from(drawn_px.0),
            (hi[1] - lo[1]) / f64::from(drawn_px.1),
        ];
        if !map.outline_mm.is_empty() {
            let mut ring: Vec<(f64, f64)> = map.outline_mm.iter().map(|p| (p[0], p[1])).collect();
            ring.push(ring[0]);
            chart
                .draw_series(std::iter::once(PathElement::new(
                    ring,
                    RGBColor(150, 150, 150).stroke_width(1),
                )))
                .map_err(err)?;
        }
        let colour = COLOURS[map.colour % COLOURS.len()];
        let head = 7.0 * mm_per_px[0];
        for (t, e) in map.targets_mm.iter().zip(map.error_um) {
            let tip = (t[0] + e[0] * mm_per_um, t[1] + e[1] * mm_per_um);
            chart
                .draw_series(arrow(
                    (t[0], t[1]),
                    tip,
                    head,
                    HEAD_HALF_ANGLE_RAD,
                    colour.stroke_width(2),
                ))
                .map_err(err)?;
        }
        chart
            .draw_series(
                map.targets_mm
                    .iter()
                    .map(|t| Circle::new((t[0], t[1]), 2, BLACK.filled())),
            )
            .map_err(err)?;
        if scale_um > 0.0 {
            // The scale arrow: bottom left, inside the padding below the targets.
            let from = (lo[0] + 40.0 * mm_per_px[0], lo[1] + 25.0 * mm_per_px[1]);
            let to = (from.0 + scale_um * mm_per_um, from.1);
            chart
                .draw_series(arrow(
                    from,
                    to,
                    head,
                    HEAD_HALF_ANGLE_RAD,
                    BLACK.stroke_width(3),
                ))
                .map_err(err)?;
            let label = format!("{} µm", fmt_um(scale_um));
            chart
                .draw_series(std::iter::once(Text::new(
                    label,
                    (from.0, from.1 + 22.0 * mm_per_px[1]),
                    ("sans-serif", 17).into_font(),
                )))
                .map_err(err)?;
        }
        Ok(MapScale {
            mm_per_px,
            arrow_mm_per_um: mm_per_um,
            scale_arrow_um: scale_um,
        })
    })?;
    Ok((png, scale))
}

/// A length in µm as a scale label (no trailing zeros).
fn fmt_um(v: f64) -> String {
    if v >= 1.0 {
        format!("{v:.0}")
    } else {
        format!("{v}")
    }
}

/// One target of an ISO 230-2 chart (µm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeviationPoint {
    pub position_mm: f64,
    pub mean_up_um: f64,
    pub s_up_um: f64,
    pub mean_down_um: f64,
    pub s_down_um: f64,
}

/// One panel of the chart: a calibration state of the line.
pub struct DeviationPanel<'a> {
    pub title: String,
    /// Figures written under the panel.
    pub figures: Vec<String>,
    pub points: &'a [DeviationPoint],
}

const PANEL_PX: (u32, u32) = (760, 600);
const PANEL_BAND_PX: u32 = 80;

/// The ISO 230-2 deviation-versus-position chart of one axis line (module doc), panels side
/// by side; `position` names the axis ("x (mm)").
pub fn deviation_chart_png(
    title: &str,
    position: &str,
    panels: &[DeviationPanel<'_>],
) -> Result<Vec<u8>, IoError> {
    if panels.is_empty() || panels.iter().any(|p| p.points.len() < 2) {
        return Err(IoError::Invalid(format!(
            "chart '{title}': every panel needs at least 2 targets"
        )));
    }
    let finite = |d: &DeviationPoint| {
        [
            d.position_mm,
            d.mean_up_um,
            d.s_up_um,
            d.mean_down_um,
            d.s_down_um,
        ]
        .iter()
        .all(|v| v.is_finite())
    };
    if !panels.iter().flat_map(|p| p.points).all(finite) {
        return Err(IoError::Invalid(format!(
            "chart '{title}': a figure is not finite"
        )));
    }
    let size = (PANEL_PX.0 * panels.len() as u32, PANEL_PX.1 + 40);
    let (png, ()) = render(size, |root| {
        let (head, body) = root.split_vertically(40);
        head.draw(&Text::new(
            title.to_string(),
            (15, 8),
            ("sans-serif", 22).into_font(),
        ))
        .map_err(err)?;
        for (area, panel) in body.split_evenly((1, panels.len())).iter().zip(panels) {
            let (plot, band) = area.split_vertically(PANEL_PX.1 - PANEL_BAND_PX);
            draw_panel(&plot, position, panel)?;
            text_band(&band, "", &panel.figures)?;
        }
        Ok(())
    })?;
    Ok(png)
}

fn draw_panel(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    position: &str,
    panel: &DeviationPanel<'_>,
) -> Result<(), IoError> {
    let p = panel.points;
    let x_lo = p
        .iter()
        .map(|d| d.position_mm)
        .fold(f64::INFINITY, f64::min);
    let x_hi = p
        .iter()
        .map(|d| d.position_mm)
        .fold(f64::NEG_INFINITY, f64::max);
    let y_lo = p
        .iter()
        .map(|d| (d.mean_up_um - 2.0 * d.s_up_um).min(d.mean_down_um - 2.0 * d.s_down_um))
        .fold(0.0, f64::min);
    let y_hi = p
        .iter()
        .map(|d| (d.mean_up_um + 2.0 * d.s_up_um).max(d.mean_down_um + 2.0 * d.s_down_um))
        .fold(0.0, f64::max);
    let (xp, yp) = (
        0.04 * (x_hi - x_lo).max(1e-3),
        0.12 * (y_hi - y_lo).max(1e-3),
    );
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 19))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(70)
        .build_cartesian_2d(x_lo - xp..x_hi + xp, y_lo - yp..y_hi + 2.5 * yp)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(position)
        .y_desc("deviation (µm)")
        .label_style(("sans-serif", 14))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    let (up, down, mid) = (COLOURS[0], COLOURS[1], BLACK);
    // ±2s bands first (under the lines).
    for (colour, mean, s) in [
        (
            up,
            &|d: &DeviationPoint| d.mean_up_um,
            &|d: &DeviationPoint| d.s_up_um,
        ),
        (
            down,
            &|d: &DeviationPoint| d.mean_down_um,
            &|d: &DeviationPoint| d.s_down_um,
        ),
    ]
        as [(
            RGBColor,
            &dyn Fn(&DeviationPoint) -> f64,
            &dyn Fn(&DeviationPoint) -> f64,
        ); 2]
    {
        let mut ring: Vec<(f64, f64)> = p
            .iter()
            .map(|d| (d.position_mm, mean(d) + 2.0 * s(d)))
            .collect();
        ring.extend(
            p.iter()
                .rev()
                .map(|d| (d.position_mm, mean(d) - 2.0 * s(d))),
        );
        chart
            .draw_series(std::iter::once(Polygon::new(
                ring,
                colour.mix(0.18).filled(),
            )))
            .map_err(err)?;
        for sign in [1.0, -1.0] {
            chart
                .draw_series(LineSeries::new(
                    p.iter()
                        .map(|d| (d.position_mm, mean(d) + sign * 2.0 * s(d))),
                    colour.mix(0.6).stroke_width(1),
                ))
                .map_err(err)?;
        }
    }
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(x_lo - xp, 0.0), (x_hi + xp, 0.0)],
            RGBColor(120, 120, 120).stroke_width(1),
        )))
        .map_err(err)?;
    let line = |f: &dyn Fn(&DeviationPoint) -> f64| {
        p.iter().map(|d| (d.position_mm, f(d))).collect::<Vec<_>>()
    };
    chart
        .draw_series(LineSeries::new(line(&|d| d.mean_up_um), up.stroke_width(2)))
        .map_err(err)?
        .label("mean ↑ (band: ± 2s↑)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], up.stroke_width(3)));
    chart
        .draw_series(LineSeries::new(
            line(&|d| d.mean_down_um),
            down.stroke_width(2),
        ))
        .map_err(err)?
        .label("mean ↓ (band: ± 2s↓)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], down.stroke_width(3)));
    chart
        .draw_series(DashedLineSeries::new(
            line(&|d| 0.5 * (d.mean_up_um + d.mean_down_um)),
            8,
            5,
            mid.stroke_width(2),
        ))
        .map_err(err)?
        .label("mean bidirectional")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], mid.stroke_width(2)));
    chart
        .draw_series(
            p.iter()
                .map(|d| TriangleMarker::new((d.position_mm, d.mean_up_um), 6, up.filled())),
        )
        .map_err(err)?;
    chart
        .draw_series(
            p.iter()
                .map(|d| Circle::new((d.position_mm, d.mean_down_um), 4, down.filled())),
        )
        .map_err(err)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn is_png(b: &[u8]) -> bool {
        b.len() > 100 && &b[1..4] == b"PNG"
    }

    #[test]
    fn round_lengths() {
        assert_eq!(round_length_below(7.3), 5.0);
        assert_eq!(round_length_below(1340.0), 1000.0);
        assert_eq!(round_length_below(2.0), 2.0);
        assert_eq!(round_length_below(0.35), 0.2);
    }

    /// The map's axes have the same scale whatever the extent's shape, and the magnification
    /// makes the longest arrow a fixed share of the workspace.
    #[test]
    fn the_error_map_has_equal_axis_scales() {
        for (w, h) in [(100.0, 150.0), (300.0, 20.0), (10.0, 10.0)] {
            let targets: Vec<[f64; 2]> = (0..30)
                .map(|k| [w * (k % 6) as f64 / 5.0, h * (k / 6) as f64 / 4.0])
                .collect();
            let errors: Vec<[f64; 2]> = (0..30).map(|k| [k as f64, -2.0]).collect();
            let outline = [[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]];
            let (png, s) = error_map_png(&ErrorMap {
                title: "t",
                summary: &["max".into()],
                targets_mm: &targets,
                error_um: &errors,
                outline_mm: &outline,
                colour: 0,
            })
            .unwrap();
            assert!(is_png(&png));
            assert!(
                (s.mm_per_px[0] / s.mm_per_px[1] - 1.0).abs() < 0.01,
                "{w}x{h}: {:?}",
                s.mm_per_px
            );
            let longest = 29f64.hypot(2.0);
            assert!((longest * s.arrow_mm_per_um - MAP_ARROW_SHARE * w.max(h)).abs() < 1e-9);
            assert_eq!(s.scale_arrow_um, 10.0);
        }
        let bad = error_map_png(&ErrorMap {
            title: "t",
            summary: &[],
            targets_mm: &[[0.0, f64::NAN]],
            error_um: &[[0.0, 0.0]],
            outline_mm: &[],
            colour: 0,
        });
        assert!(bad.is_err());
    }

    #[test]
    fn the_deviation_chart_draws_and_refuses_nan() {
        let pts: Vec<DeviationPoint> = (0..5)
            .map(|k| DeviationPoint {
                position_mm: 10.0 * k as f64,
                mean_up_um: 1.0,
                s_up_um: 0.5,
                mean_down_um: -1.0,
                s_down_um: 0.2,
            })
            .collect();
        let panel = |p| DeviationPanel {
            title: "after".into(),
            figures: vec!["A = 3 µm".into()],
            points: p,
        };
        assert!(is_png(
            &deviation_chart_png("x line", "x (mm)", &[panel(&pts), panel(&pts)]).unwrap()
        ));
        let mut nan = pts.clone();
        nan[2].s_up_um = f64::NAN;
        assert!(deviation_chart_png("x line", "x (mm)", &[panel(&nan)]).is_err());
        assert!(deviation_chart_png("x line", "x (mm)", &[panel(&pts[..1])]).is_err());
    }
}
