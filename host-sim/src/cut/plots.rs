//! The cut's plots, as PNG bytes (staged with the other outputs): the part with the gantry's
//! path and the micro's excursion in its workspace, and the speed and acceleration of both
//! stages over time with their limits. Long runs are thinned for drawing: paths to at most
//! [`PATH_POINTS`] points, time series to the largest value of each of [`TIME_POINTS`] buckets
//! (so no peak is lost).

use super::execute::Executed;
use super::micro::MicroLimits;
use super::path::Segment;
use super::Planned;
use crate::io::plot::{err, legend, render, Area, COLOURS};
use crate::io::IoError;
use crate::machine_spec::MachineSpec;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

/// Most points of a drawn path.
pub const PATH_POINTS: usize = 20_000;
/// Buckets of a drawn time series.
pub const TIME_POINTS: usize = 3_000;

/// Points along a segment, dense enough to draw an arc smoothly.
fn polyline(s: &Segment) -> Vec<(f64, f64)> {
    let n = match s {
        Segment::Line { .. } => 1,
        Segment::Arc { sweep_rad, .. } => ((sweep_rad.abs() / 0.1).ceil() as usize).max(2),
    };
    (0..=n)
        .map(|k| {
            let p = s.at(s.length_mm() * k as f64 / n as f64).position_mm;
            (p[0], p[1])
        })
        .collect()
}

fn thin<T: Copy>(x: &[T], most: usize) -> Vec<T> {
    let step = x.len().div_ceil(most.max(1)).max(1);
    x.iter().step_by(step).copied().collect()
}

/// `(t, value)` with the largest |value| of each bucket.
fn peaks_over_time(v: &[f64], dt: f64) -> Vec<(f64, f64)> {
    let step = v.len().div_ceil(TIME_POINTS).max(1);
    v.chunks(step)
        .enumerate()
        .map(|(b, c)| {
            let m = c.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            ((b * step) as f64 * dt, m)
        })
        .collect()
}

/// Ranges of equal scale holding `lo..hi` in an area of `w × h` pixels.
fn equal_ranges(lo: [f64; 2], hi: [f64; 2], w: f64, h: f64) -> ([f64; 2], [f64; 2]) {
    let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let mut half = [
        (hi[0] - lo[0]) / 2.0 * 1.08 + 1.0,
        (hi[1] - lo[1]) / 2.0 * 1.08 + 1.0,
    ];
    if half[0] / half[1] < w / h {
        half[0] = half[1] * w / h;
    } else {
        half[1] = half[0] * h / w;
    }
    (
        [c[0] - half[0], c[0] + half[0]],
        [c[1] - half[1], c[1] + half[1]],
    )
}

/// The part: cuts, rapids and the gantry's executed path (left); the micro's executed
/// excursion in its workspace, with the margin (right).
pub fn part_png(
    spec: &MachineSpec,
    planned: &Planned,
    executed: &[Executed],
    micro: &MicroLimits,
) -> Result<Vec<u8>, IoError> {
    let moves = &planned.layout.moves;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for m in moves {
        let (a, b) = m.segment.bounds_mm();
        for i in 0..2 {
            lo[i] = lo[i].min(a[i]);
            hi[i] = hi[i].max(b[i]);
        }
    }
    let gantry: Vec<(f64, f64)> = thin(executed, PATH_POINTS)
        .iter()
        .map(|e| (e.gantry_mm[0], e.gantry_mm[1]))
        .collect();
    let excursion: Vec<(f64, f64)> = thin(executed, PATH_POINTS)
        .iter()
        .map(|e| {
            (
                micro.centre_mm[0] + e.micro_mm[0],
                micro.centre_mm[1] + e.micro_mm[1],
            )
        })
        .collect();
    let title = format!("the part on {}: cuts, rapids, the gantry's path", spec.name);
    render(1700, 800, |root| {
        let (left, right) = root.split_horizontally(1000);
        draw_part(&left, &title, moves, &gantry, lo, hi)?;
        draw_micro(&right, micro, &excursion)
    })
}

fn draw_part(
    area: &Area<'_>,
    title: &str,
    moves: &[super::gcode::Move],
    gantry: &[(f64, f64)],
    lo: [f64; 2],
    hi: [f64; 2],
) -> Result<(), IoError> {
    let mut chart = plan_chart(area, title, [lo, hi], 900.0, ["x (mm)", "y (mm)"])?;
    let grey = RGBColor(170, 170, 170);
    let mut first = [true, true];
    for m in moves {
        let (colour, width, k, label) = if m.laser_on {
            (BLACK, 2, 0, "cut (beam on)")
        } else {
            (grey, 1, 1, "rapid / beam off")
        };
        let s = chart
            .draw_series(LineSeries::new(
                polyline(&m.segment),
                colour.stroke_width(width),
            ))
            .map_err(err)?;
        if first[k] {
            s.label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
            first[k] = false;
        }
    }
    trace(&mut chart, gantry, COLOURS[0], "gantry (executed)")?;
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// A plan view of `bounds_mm` (`[low, high]` corners) at equal x and y scales in `width_px` ×
/// 680 px, its mesh drawn with the axes named `desc`.
fn plan_chart<'a, 'b>(
    area: &'a Area<'b>,
    title: &str,
    bounds_mm: [[f64; 2]; 2],
    width_px: f64,
    desc: [&str; 2],
) -> Result<ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>, IoError>
{
    let (xr, yr) = equal_ranges(bounds_mm[0], bounds_mm[1], width_px, 680.0);
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(xr[0]..xr[1], yr[0]..yr[1])
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(desc[0])
        .y_desc(desc[1])
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    Ok(chart)
}

/// A thin line through `points` in `colour`, named `label` in the legend (drawn thicker there).
fn trace<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    points: &[(f64, f64)],
    colour: RGBColor,
    label: &str,
) -> Result<(), IoError> {
    chart
        .draw_series(LineSeries::new(
            points.iter().copied(),
            colour.stroke_width(1),
        ))
        .map_err(err)?
        .label(label)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(3)));
    Ok(())
}

fn draw_micro(
    area: &Area<'_>,
    micro: &MicroLimits,
    excursion: &[(f64, f64)],
) -> Result<(), IoError> {
    let v = micro.region.vertices_mm();
    let (x, y) = micro.region.bounds_mm();
    let mut chart = plan_chart(
        area,
        "the micro's excursion (executed)",
        [[x[0], y[0]], [x[1], y[1]]],
        600.0,
        ["micro x (mm)", "micro y (mm)"],
    )?;
    let mut outline: Vec<(f64, f64)> = v.iter().map(|p| (p[0], p[1])).collect();
    outline.push(outline[0]);
    chart
        .draw_series(LineSeries::new(outline, BLACK.stroke_width(2)))
        .map_err(err)?
        .label("workspace")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
    // The margin: each vertex moved inwards along its bisector (exact for a rectangle).
    let inner: Vec<(f64, f64)> = (0..v.len())
        .map(|i| {
            let (a, b, c) = (v[(i + v.len() - 1) % v.len()], v[i], v[(i + 1) % v.len()]);
            let n = |p: [f64; 2], q: [f64; 2]| {
                let e = [q[0] - p[0], q[1] - p[1]];
                let l = e[0].hypot(e[1]);
                [-e[1] / l, e[0] / l]
            };
            let (n1, n2) = (n(a, b), n(b, c));
            let s = [n1[0] + n2[0], n1[1] + n2[1]];
            let k = micro.margin_mm / (1.0 + n1[0] * n2[0] + n1[1] * n2[1]).max(1e-9);
            (b[0] + s[0] * k, b[1] + s[1] * k)
        })
        .collect();
    let mut inner_closed = inner.clone();
    inner_closed.push(inner[0]);
    chart
        .draw_series(LineSeries::new(
            inner_closed,
            RGBColor(120, 120, 120).stroke_width(1),
        ))
        .map_err(err)?
        .label(format!("less the {} mm margin", micro.margin_mm))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RGBColor(120, 120, 120)));
    trace(&mut chart, excursion, COLOURS[1], "micro tool point")?;
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// One panel of values over time with a limit line.
fn time_panel(
    area: &Area<'_>,
    title: &str,
    y_label: &str,
    series: &[(&str, Vec<(f64, f64)>)],
    limit: f64,
    t_end: f64,
) -> Result<(), IoError> {
    let top = series
        .iter()
        .flat_map(|(_, s)| s.iter().map(|p| p.1))
        .fold(limit, f64::max)
        * 1.1;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(35)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..t_end.max(1e-3), 0.0..top.max(1e-9))
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("t (s)")
        .y_desc(y_label)
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(err)?;
    for (k, (label, s)) in series.iter().enumerate() {
        let c = COLOURS[k % COLOURS.len()];
        trace(&mut chart, s, c, label)?;
    }
    chart
        .draw_series(LineSeries::new(
            vec![(0.0, limit), (t_end, limit)],
            BLACK.stroke_width(2),
        ))
        .map_err(err)?
        .label("limit")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// Speed and acceleration of both stages over time (executed), with their limits.
pub fn motion_png(
    executed: &[Executed],
    dt: f64,
    gantry_limits: [f64; 2],
    micro: &MicroLimits,
) -> Result<Vec<u8>, IoError> {
    let n = executed.len();
    let diff = |f: &dyn Fn(usize) -> f64, order: usize| -> Vec<f64> {
        (0..n)
            .map(|k| {
                if k == 0 || k + 1 >= n {
                    return 0.0;
                }
                match order {
                    1 => (f(k + 1) - f(k - 1)) / (2.0 * dt),
                    _ => (f(k + 1) - 2.0 * f(k) + f(k - 1)) / (dt * dt),
                }
            })
            .collect()
    };
    let gx = |k: usize| executed[k].gantry_mm[0];
    let gy = |k: usize| executed[k].gantry_mm[1];
    let mx = |k: usize| executed[k].micro_mm[0];
    let my = |k: usize| executed[k].micro_mm[1];
    let norm = |a: Vec<f64>, b: Vec<f64>| -> Vec<f64> {
        a.iter().zip(&b).map(|(x, y)| x.hypot(*y)).collect()
    };
    let gvx = peaks_over_time(&diff(&gx, 1), dt);
    let gvy = peaks_over_time(&diff(&gy, 1), dt);
    let gax = peaks_over_time(&diff(&gx, 2), dt);
    let gay = peaks_over_time(&diff(&gy, 2), dt);
    let mv = peaks_over_time(&norm(diff(&mx, 1), diff(&my, 1)), dt);
    let ma = peaks_over_time(&norm(diff(&mx, 2), diff(&my, 2)), dt);
    let t_end = n as f64 * dt;
    render(1500, 1000, |root| {
        let panels = root.split_evenly((2, 2));
        time_panel(
            &panels[0],
            "gantry speed per axis",
            "mm/s",
            &[("x", gvx), ("y", gvy)],
            gantry_limits[0],
            t_end,
        )?;
        time_panel(
            &panels[1],
            "micro speed (relative to the gantry)",
            "mm/s",
            &[("|v|", mv)],
            micro.speed_mm_s,
            t_end,
        )?;
        time_panel(
            &panels[2],
            "gantry acceleration per axis",
            "mm/s²",
            &[("x", gax), ("y", gay)],
            gantry_limits[1],
            t_end,
        )?;
        time_panel(
            &panels[3],
            "micro acceleration (relative to the gantry)",
            "mm/s²",
            &[("|a|", ma)],
            micro.accel_mm_s2,
            t_end,
        )
    })
}
