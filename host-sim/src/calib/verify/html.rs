//! The report as one self-contained HTML page (no external file, script or style sheet: the
//! plots are PNGs embedded as base64 `data:` URLs), what the customer receives:
//!
//! 1. the summary table: every headline figure before, after and the factor between them;
//! 2. the notes (fewer runs than ISO 230-2 asks for, targets outside the workspace);
//! 3. the error-vector map of each state (`crate::io::verify_plot::error_map_png`);
//! 4. per axis line: the ISO 230-2 chart (before | after), the figures of each state and the
//!    per-target table (x̄↑, s↑, x̄↓, s↓, Bi, x̄i);
//! 5. the definitions, the inputs and how the page was made.
//!
//! Every text from outside (machine name, file names, notes) is HTML-escaped.

use super::{matching_line, StageReport, VerifyReport};
use crate::calib::accuracy::LineStats;
use crate::calib::CalibError;
use crate::io::verify_plot::{
    deviation_chart_png, error_map_png, DeviationPanel, DeviationPoint, ErrorMap,
};
use crate::machine_spec::MachineSpec;
use base64::Engine as _;
use std::fmt::Write as _;

/// `<`, `>`, `&`, `"` escaped.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A figure in µm with the digits that matter (3 significant, at most 2 decimals).
pub fn um(v: f64) -> String {
    if !v.is_finite() {
        "∞".into()
    } else if v.abs() < 10.0 {
        format!("{v:.2}")
    } else if v.abs() < 100.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.0}")
    }
}

fn img(png: &[u8], alt: &str) -> String {
    format!(
        "<img alt=\"{}\" src=\"data:image/png;base64,{}\">",
        escape(alt),
        base64::engine::general_purpose::STANDARD.encode(png)
    )
}

/// "x line at y = 0 mm".
pub fn line_name(l: &LineStats) -> String {
    format!(
        "{} line at {} = {} mm",
        l.axis,
        if l.axis == "x" { "y" } else { "x" },
        l.at_mm
    )
}

/// The headline figures of a line: (name, value).
fn line_figures(l: &LineStats) -> Vec<(&'static str, f64)> {
    let (i, v) = (&l.iso_230_2, &l.vdi_3441);
    vec![
        ("ISO 230-2 accuracy A", i.a_um),
        ("ISO 230-2 repeatability R", i.r_um),
        ("ISO 230-2 repeatability R↑", i.r_up_um),
        ("ISO 230-2 repeatability R↓", i.r_down_um),
        ("ISO 230-2 systematic positioning error E", i.e_um),
        (
            "ISO 230-2 mean bidirectional positional deviation M",
            i.m_um,
        ),
        ("ISO 230-2 reversal value B", i.b_um),
        ("ISO 230-2 mean reversal value B̄", i.b_mean_um),
        ("VDI 3441 positioning uncertainty P", v.p_um),
        ("VDI 3441 position scatter Ps", v.ps_um),
        ("VDI 3441 reversal span U", v.u_um),
        ("VDI 3441 positional deviation Pa", v.pa_um),
    ]
}

/// One row of the summary table.
fn summary_row(out: &mut String, name: &str, before: Option<f64>, after: f64) {
    let factor = match before {
        Some(b) if after > 0.0 => format!("{:.1}×", b / after),
        Some(_) => "—".into(),
        None => String::new(),
    };
    let b = before.map(um).unwrap_or_default();
    let _ = writeln!(
        out,
        "<tr><td>{}</td><td>{b}</td><td>{}</td><td>{factor}</td></tr>",
        escape(name),
        um(after)
    );
}

fn summary_table(out: &mut String, before: Option<&StageReport>, after: &StageReport) {
    out.push_str("<h2>Summary</h2>\n<table>\n<tr><th>figure (µm)</th><th>before calibration</th><th>after calibration</th><th>improvement</th></tr>\n");
    let (bp, ap) = (before.map(|b| &b.position), &after.position);
    summary_row(
        out,
        &format!(
            "2-D position error, max ({} verification targets)",
            ap.n_points
        ),
        bp.map(|p| p.max_um),
        ap.max_um,
    );
    summary_row(
        out,
        "2-D position error, RMS",
        bp.map(|p| p.rms_um),
        ap.rms_um,
    );
    for l in &after.lines {
        let b = before.and_then(|b| matching_line(&b.lines, l));
        let bf = b.map(line_figures);
        for (k, (name, v)) in line_figures(l).into_iter().enumerate() {
            // The summary keeps A, R, E, B and P, Ps; the rest are in the line's section.
            if [0, 1, 4, 6, 8, 9].contains(&k) {
                summary_row(
                    out,
                    &format!("{}: {name}", line_name(l)),
                    bf.as_ref().map(|f| f[k].1),
                    v,
                );
            }
        }
    }
    out.push_str("</table>\n");
}

fn position_lines(s: &StageReport) -> Vec<String> {
    let p = &s.position;
    vec![
        format!(
            "2-D position error: max {} µm, RMS {} µm over {} targets",
            um(p.max_um),
            um(p.rms_um),
            p.n_points
        ),
        format!(
            "mean error ({}, {}) µm; max |Δx| {} µm, |Δy| {} µm",
            um(p.mean_um[0]),
            um(p.mean_um[1]),
            um(p.max_abs_um[0]),
            um(p.max_abs_um[1])
        ),
    ]
}

fn stage_title(stage: &str) -> &'static str {
    if stage == "before" {
        "before calibration"
    } else {
        "after calibration"
    }
}

fn line_section(
    out: &mut String,
    l_after: &LineStats,
    stages: &[&StageReport],
) -> Result<(), CalibError> {
    let name = line_name(l_after);
    let _ = writeln!(out, "<h2>{}</h2>", escape(&name));
    let lines: Vec<(&StageReport, &LineStats)> = stages
        .iter()
        .filter_map(|s| matching_line(&s.lines, l_after).map(|l| (*s, l)))
        .collect();
    let points: Vec<Vec<DeviationPoint>> = lines
        .iter()
        .map(|(_, l)| {
            l.targets
                .iter()
                .map(|t| DeviationPoint {
                    position_mm: t.position_mm,
                    mean_up_um: t.mean_up_um,
                    s_up_um: t.s_up_um,
                    mean_down_um: t.mean_down_um,
                    s_down_um: t.s_down_um,
                })
                .collect()
        })
        .collect();
    let panels: Vec<DeviationPanel<'_>> = lines
        .iter()
        .zip(&points)
        .map(|((s, l), p)| DeviationPanel {
            title: format!("{}: ISO 230-2 deviations", stage_title(s.stage)),
            figures: vec![
                format!(
                    "A {} µm, R {} µm (R↑ {}, R↓ {}), E {} µm, B {} µm",
                    um(l.iso_230_2.a_um),
                    um(l.iso_230_2.r_um),
                    um(l.iso_230_2.r_up_um),
                    um(l.iso_230_2.r_down_um),
                    um(l.iso_230_2.e_um),
                    um(l.iso_230_2.b_um)
                ),
                format!(
                    "VDI 3441: P {} µm, Ps {} µm, U {} µm, Pa {} µm",
                    um(l.vdi_3441.p_um),
                    um(l.vdi_3441.ps_um),
                    um(l.vdi_3441.u_um),
                    um(l.vdi_3441.pa_um)
                ),
            ],
            points: p,
        })
        .collect();
    let png = deviation_chart_png(
        &format!("{name}: positional deviation (measured − target) against position"),
        &format!("{} (mm)", l_after.axis),
        &panels,
    )?;
    out.push_str(&img(&png, &format!("ISO 230-2 chart of the {name}")));
    out.push('\n');
    // The figures of each state side by side.
    out.push_str("<table>\n<tr><th>figure (µm)</th>");
    for (s, _) in &lines {
        let _ = write!(out, "<th>{}</th>", stage_title(s.stage));
    }
    out.push_str("<th>per metre (after, µm/m)</th></tr>\n");
    let figs: Vec<Vec<(&str, f64)>> = lines.iter().map(|(_, l)| line_figures(l)).collect();
    let per_m_key = ["a", "r", "", "", "", "m", "b", "", "p", "ps", "u", "pa"];
    for (k, (name, _)) in figs[0].iter().enumerate() {
        let _ = write!(out, "<tr><td>{}</td>", escape(name));
        for f in &figs {
            let _ = write!(out, "<td>{}</td>", um(f[k].1));
        }
        let pm = l_after
            .per_m
            .get(per_m_key[k])
            .map(|v| um(*v))
            .unwrap_or_default();
        let _ = writeln!(out, "<td>{pm}</td></tr>");
    }
    let _ = writeln!(
        out,
        "<tr><td>line length (mm)</td><td colspan=\"{}\">{}</td></tr>\n</table>",
        lines.len() + 1,
        l_after.length_mm
    );
    // Per target, per state.
    for (s, l) in &lines {
        let _ = writeln!(
            out,
            "<h3>{}: per target (µm)</h3>\n<table>\n<tr><th>position (mm)</th><th>n↑</th><th>x̄↑</th><th>s↑</th><th>n↓</th><th>x̄↓</th><th>s↓</th><th>Bi = x̄↑ − x̄↓</th><th>x̄ = (x̄↑ + x̄↓)/2</th></tr>",
            stage_title(s.stage)
        );
        for t in &l.targets {
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                t.position_mm,
                t.n_up,
                um(t.mean_up_um),
                um(t.s_up_um),
                t.n_down,
                um(t.mean_down_um),
                um(t.s_down_um),
                um(t.mean_up_um - t.mean_down_um),
                um(0.5 * (t.mean_up_um + t.mean_down_um))
            );
        }
        out.push_str("</table>\n");
    }
    Ok(())
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1560px;margin:2em auto;padding:0 1em;color:#222}\
table{border-collapse:collapse;margin:0.8em 0}td,th{border:1px solid #bbb;padding:0.25em 0.6em;text-align:right}\
td:first-child,th:first-child{text-align:left}th{background:#eee}img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}\
.maps{display:flex;flex-wrap:wrap;gap:1em}.maps img{max-width:760px}.note{background:#fff6d6;padding:0.4em 0.8em}";

/// The definitions section (what each figure means; `docs/reference/calibration-tools.md` has the whole text).
const DEFINITIONS: &str = "<h2>Definitions</h2>\n<p>Deviation x = measured − target position along the line's axis, \
per target i and approach direction (↑ positive, ↓ negative; the direction is the last move along the axis within the run). \
x̄i↑, x̄i↓: mean deviations; si↑, si↓: estimators of the standard deviation (n − 1); x̄i = (x̄i↑ + x̄i↓)/2.</p>\n<ul>\n\
<li>ISO 230-2: reversal value Bi = x̄i↑ − x̄i↓, B = max |Bi|, mean reversal B̄ = mean Bi; repeatability Ri↑ = 4si↑, R↑ = max Ri↑ (↓ alike), \
Ri = max(2si↑ + 2si↓ + |Bi|, Ri↑, Ri↓), R = max Ri; systematic positioning error E = max(x̄i↑, x̄i↓) − min(x̄i↑, x̄i↓); \
mean bidirectional positional deviation M = max x̄i − min x̄i; accuracy A = max(x̄i↑ + 2si↑, x̄i↓ + 2si↓) − min(x̄i↑ − 2si↑, x̄i↓ − 2si↓).</li>\n\
<li>VDI/DGQ 3441: reversal span U = max |Bi|; position scatter Ps = max 6·(si↑ + si↓)/2; positional deviation Pa = max x̄i − min x̄i; \
positioning uncertainty P = max(x̄i + (|Bi| + Psi)/2) − min(x̄i − (|Bi| + Psi)/2).</li>\n\
<li>2-D position error: the length of measured − target at every verification target; its maximum and RMS.</li>\n</ul>\n";

/// The page. `inputs`: (what, file) of every measurement file read.
pub fn render(
    report: &VerifyReport,
    spec: &MachineSpec,
    inputs: &[(String, String)],
) -> Result<String, CalibError> {
    let after = report
        .stage("after")
        .ok_or_else(|| crate::calib::invalid!("the report has no after stage"))?;
    let before = report.stage("before");
    let title = format!("Positioning accuracy of machine '{}'", report.machine);
    let mut out = String::new();
    let _ = writeln!(out, "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n<style>{STYLE}</style>\n</head>\n<body>", escape(&title));
    let _ = writeln!(
        out,
        "<h1>{}</h1>\n<p>{}. Positions in mm (machine frame), deviations in µm.</p>",
        escape(&title),
        escape(report.standards)
    );
    summary_table(&mut out, before, after);
    if !report.notes.is_empty() {
        out.push_str("<h2>Notes</h2>\n<ul>\n");
        for n in &report.notes {
            let _ = writeln!(out, "<li class=\"note\">{}</li>", escape(n));
        }
        out.push_str("</ul>\n");
    }
    out.push_str("<h2>Error vectors at the verification targets</h2>\n<p>Arrows from each target (dot) along measured − target, magnified (the scale arrow gives the length of a round number of µm); x and y at the same scale; the grey outline is the workspace. Each map has its own magnification.</p>\n<div class=\"maps\">\n");
    let outline = spec.workspace.region.vertices_mm();
    for (k, s) in report.stages.iter().enumerate() {
        let (targets, errors): (Vec<[f64; 2]>, Vec<[f64; 2]>) =
            s.vectors.iter().map(|v| (v.target_mm, v.error_um)).unzip();
        let summary = position_lines(s);
        let t = format!("{}: measured − target", stage_title(s.stage));
        let colour = if report.stages.len() == 2 && k == 0 {
            1
        } else {
            0
        };
        let (png, _) = error_map_png(&ErrorMap {
            title: &t,
            summary: &summary,
            targets_mm: &targets,
            error_um: &errors,
            outline_mm: outline,
            colour,
        })?;
        out.push_str(&img(&png, &t));
        out.push('\n');
    }
    out.push_str("</div>\n");
    let stages: Vec<&StageReport> = report.stages.iter().collect();
    for l in &after.lines {
        line_section(&mut out, l, &stages)?;
    }
    out.push_str(DEFINITIONS);
    out.push_str("<h2>Inputs</h2>\n<ul>\n");
    for (what, file) in inputs {
        let _ = writeln!(
            out,
            "<li>{}: <code>{}</code></li>",
            escape(what),
            escape(file)
        );
    }
    let _ = writeln!(
        out,
        "</ul>\n<p>Made by <code>host-sim verify</code> {}.</p>\n</body>\n</html>",
        env!("CARGO_PKG_VERSION")
    );
    Ok(out)
}
