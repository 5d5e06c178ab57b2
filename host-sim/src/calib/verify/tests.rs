//! The report's figures on small tables computed by hand (the comments show the arithmetic).

use super::*;

fn row(run: u32, target: [f64; 2], dev_um: [f64; 2], line: usize) -> Measurement {
    Measurement {
        theta_deg: [0.0, 0.0],
        measured_mm: [target[0] + dev_um[0] * 1e-3, target[1] + dev_um[1] * 1e-3],
        target_mm: Some(target),
        dir: None,
        run: Some(run),
        t_s: None,
        line,
    }
}

/// Deviations (µm) per run: `up[k]` at the line's targets ascending, `down[k]` descending.
struct Line {
    axis: usize,
    at_mm: f64,
    targets_mm: [f64; 3],
    up: [[f64; 3]; 3],
    down: [[f64; 3]; 3],
}

/// The x line at y = 0, targets 0, 50, 100 mm, 3 runs (µm):
///
/// | target | ↑ runs | x̄↑ | s↑ | ↓ runs | x̄↓ | s↓ | Bi | x̄i |
/// |---|---|---|---|---|---|---|---|---|
/// | 0   | 1, 2, 3 | 2 | 1 | −1, 0, 1 | 0 | 1 | 2 | 1 |
/// | 50  | 2, 4, 6 | 4 | 2 | 1, 2, 3 | 2 | 1 | 2 | 3 |
/// | 100 | 0, 0, 0 | 0 | 0 | −3, −2, −1 | −2 | 1 | 2 | −1 |
///
/// (s = √(Σ(x − x̄)²/(n − 1)): {1,2,3} → √(2/2) = 1, {2,4,6} → √(8/2) = 2.)
fn x_line() -> Line {
    Line {
        axis: 0,
        at_mm: 0.0,
        targets_mm: [0.0, 50.0, 100.0],
        // run k: deviation at targets 0, 50, 100
        up: [[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [3.0, 6.0, 0.0]],
        // run k: deviation at targets 0, 50, 100 (measured in the order 100, 50, 0)
        down: [[-1.0, 1.0, -3.0], [0.0, 2.0, -2.0], [1.0, 3.0, -1.0]],
    }
}

/// The y line at x = 30 (off the x line's targets), targets 10, 30, 50 mm, 3 runs (µm):
///
/// | target | ↑ runs | x̄↑ | s↑ | ↓ runs | x̄↓ | s↓ | Bi | x̄i |
/// |---|---|---|---|---|---|---|---|---|
/// | 10 | 0, 0, 0 | 0 | 0 | 0, 0, 0 | 0 | 0 | 0 | 0 |
/// | 30 | 1, 1, 1 | 1 | 0 | −1, −1, −1 | −1 | 0 | 2 | 0 |
/// | 50 | 2, 3, 4 | 3 | 1 | 0, 1, 2 | 1 | 1 | 2 | 2 |
fn y_line() -> Line {
    Line {
        axis: 1,
        at_mm: 30.0,
        targets_mm: [10.0, 30.0, 50.0],
        up: [[0.0, 1.0, 2.0], [0.0, 1.0, 3.0], [0.0, 1.0, 4.0]],
        down: [[0.0, -1.0, 0.0], [0.0, -1.0, 1.0], [0.0, -1.0, 2.0]],
    }
}

/// Rows as `measure --targets repeat.csv` writes them: per run an ascending pass then a
/// descending one (starting at the last target: the reversal) of each line, scaled by `k`.
fn repeat_rows(lines: &[Line], runs: usize, k: f64) -> Vec<Measurement> {
    let mut v = Vec::new();
    for run in 0..runs {
        for l in lines {
            let at = |i: usize| {
                let mut t = [0.0; 2];
                t[l.axis] = l.targets_mm[i];
                t[1 - l.axis] = l.at_mm;
                t
            };
            let dev = |d: f64| {
                let mut e = [0.0; 2];
                e[l.axis] = k * d;
                e
            };
            for i in 0..3 {
                v.push(row(run as u32, at(i), dev(l.up[run][i]), v.len() + 2));
            }
            for i in (0..3).rev() {
                v.push(row(run as u32, at(i), dev(l.down[run][i]), v.len() + 2));
            }
        }
    }
    v
}

/// Verification: 4 targets, errors (3, 4), (0, 0), (−6, 8), (0, −5) µm: lengths 5, 0, 10, 5.
fn verify_rows(k: f64) -> Vec<Measurement> {
    [
        ([0.0, 0.0], [3.0, 4.0]),
        ([10.0, 0.0], [0.0, 0.0]),
        ([0.0, 10.0], [-6.0, 8.0]),
        ([10.0, 10.0], [0.0, -5.0]),
    ]
    .iter()
    .enumerate()
    .map(|(i, (t, e))| row(0, *t, [k * e[0], k * e[1]], i + 2))
    .collect()
}

fn stage_data(k: f64) -> StageData {
    StageData {
        verify: verify_rows(k),
        repeat: repeat_rows(&[x_line(), y_line()], 3, k),
    }
}

fn close(a: f64, b: f64, what: &str) {
    assert!(
        (a - b).abs() < 1e-6 * b.abs().max(1.0),
        "{what}: {a} vs {b}"
    );
}

#[test]
fn position_error_matches_hand_computation() {
    let (p, v) = position_error(&verify_rows(1.0)).unwrap();
    assert_eq!((p.n_points, v.len()), (4, 4));
    close(p.max_um, 10.0, "max");
    // RMS = √((25 + 0 + 100 + 25) / 4) = √37.5
    close(p.rms_um, 37.5f64.sqrt(), "rms");
    // mean = ((3 + 0 − 6 + 0)/4, (4 + 0 + 8 − 5)/4)
    close(p.mean_um[0], -0.75, "mean x");
    close(p.mean_um[1], 1.75, "mean y");
    close(p.max_abs_um[0], 6.0, "max |dx|");
    close(p.max_abs_um[1], 8.0, "max |dy|");
    // √((9 + 36)/4), √((16 + 64 + 25)/4)
    close(p.rms_axis_um[0], 11.25f64.sqrt(), "rms x");
    close(p.rms_axis_um[1], 26.25f64.sqrt(), "rms y");
    close(v[2].error_um[0], -6.0, "vector");
}

#[test]
fn iso_230_2_and_vdi_3441_match_hand_computation() {
    let r = verify(&VerifyOptions {
        spec: MachineSpec::paper(),
        before: None,
        after: stage_data(1.0),
    })
    .unwrap();
    let a = r.stage("after").unwrap();
    assert_eq!(a.lines.len(), 2);
    let (x, y) = (&a.lines[0], &a.lines[1]);
    assert_eq!(
        (x.axis, x.at_mm, x.length_mm, y.axis, y.at_mm, y.length_mm),
        ("x", 0.0, 100.0, "y", 30.0, 40.0)
    );
    // Per target and direction: the tables' x̄ and s.
    let t = &x.targets[1];
    assert_eq!((t.position_mm, t.n_up, t.n_down), (50.0, 3, 3));
    close(t.mean_up_um, 4.0, "x̄↑ at 50");
    close(t.s_up_um, 2.0, "s↑ at 50");
    close(t.mean_down_um, 2.0, "x̄↓ at 50");
    close(t.s_down_um, 1.0, "s↓ at 50");

    // x line, ISO 230-2:
    // B = max|Bi| = 2, B̄ = (2 + 2 + 2)/3 = 2;
    // R↑ = 4·max s↑ = 8, R↓ = 4·max s↓ = 4;
    // Ri = max(2s↑ + 2s↓ + |Bi|, 4s↑, 4s↓) = max(6,4,4), max(8,8,4), max(4,0,4) → R = 8;
    // E = max(2, 0, 4, 2, 0, −2) − min(…) = 4 − (−2) = 6; M = max x̄i − min x̄i = 3 − (−1) = 4;
    // A: x̄ + 2s = 4, 2 | 8, 4 | 0, 0 → 8; x̄ − 2s = 0, −2 | 0, 0 | 0, −4 → −4; A = 12.
    let i = &x.iso_230_2;
    for (v, want, what) in [
        (i.b_um, 2.0, "B"),
        (i.b_mean_um, 2.0, "B̄"),
        (i.r_up_um, 8.0, "R↑"),
        (i.r_down_um, 4.0, "R↓"),
        (i.r_um, 8.0, "R"),
        (i.e_um, 6.0, "E"),
        (i.m_um, 4.0, "M"),
        (i.a_um, 12.0, "A"),
    ] {
        close(v, want, &format!("x line {what}"));
    }
    // x line, VDI 3441: U = max|Bi| = 2; Psi = 6·(s↑ + s↓)/2 = 6, 9, 3 → Ps = 9; Pa = 4;
    // P: x̄i ± (Ui + Psi)/2 = 1 ± 4, 3 ± 5.5, −1 ± 2.5 → 8.5 − (−3.5) = 12.
    let d = &x.vdi_3441;
    for (v, want, what) in [
        (d.u_um, 2.0, "U"),
        (d.ps_um, 9.0, "Ps"),
        (d.pa_um, 4.0, "Pa"),
        (d.p_um, 12.0, "P"),
    ] {
        close(v, want, &format!("x line {what}"));
    }
    // Per metre of the 100 mm line: ×10; the paper's "±" form is half.
    close(x.per_m["p"], 120.0, "P per m");
    close(x.per_m["p_pm"], 60.0, "±P per m");

    // y line, ISO 230-2: B = 2, B̄ = (0 + 2 + 2)/3 = 4/3; R↑ = 4, R↓ = 4;
    // Ri = 0, max(2, 0, 0), max(2 + 2 + 2, 4, 4) → R = 6; E = 3 − (−1) = 4; M = 2 − 0 = 2;
    // A: x̄ + 2s = 0, 0 | 1, −1 | 5, 3 → 5; x̄ − 2s = 0, 0 | 1, −1 | 1, −1 → −1; A = 6.
    let i = &y.iso_230_2;
    for (v, want, what) in [
        (i.b_um, 2.0, "B"),
        (i.b_mean_um, 4.0 / 3.0, "B̄"),
        (i.r_up_um, 4.0, "R↑"),
        (i.r_down_um, 4.0, "R↓"),
        (i.r_um, 6.0, "R"),
        (i.e_um, 4.0, "E"),
        (i.m_um, 2.0, "M"),
        (i.a_um, 6.0, "A"),
    ] {
        close(v, want, &format!("y line {what}"));
    }
    // y line, VDI 3441: U = 2; Psi = 0, 0, 6 → Ps = 6; Pa = 2;
    // P: 0 ± 0, 0 ± 1, 2 ± 4 → 6 − (−2) = 8.
    let d = &y.vdi_3441;
    for (v, want, what) in [
        (d.u_um, 2.0, "U"),
        (d.ps_um, 6.0, "Ps"),
        (d.pa_um, 2.0, "Pa"),
        (d.p_um, 8.0, "P"),
    ] {
        close(v, want, &format!("y line {what}"));
    }
    // 3 runs: fewer than ISO 230-2's 5, said in a note; no before stage, no improvement.
    assert!(
        r.notes
            .iter()
            .any(|n| n.contains("only 3 approaches") && n.contains("ISO 230-2 asks for 5")),
        "{:?}",
        r.notes
    );
    assert!(r.improvement.is_none());
}

/// Every figure is linear in the deviations: a before stage 10x the after stage improves every
/// figure by exactly 10.
#[test]
fn before_and_after_give_the_improvement() {
    let r = verify(&VerifyOptions {
        spec: MachineSpec::paper(),
        before: Some(stage_data(10.0)),
        after: stage_data(1.0),
    })
    .unwrap();
    let stages: Vec<&str> = r.stages.iter().map(|s| s.stage).collect();
    assert_eq!(stages, ["before", "after"]);
    close(
        r.stage("before").unwrap().lines[0].iso_230_2.a_um,
        120.0,
        "A before",
    );
    let imp = r.improvement.as_ref().unwrap();
    // 2 position figures + 4 per line.
    assert_eq!(imp.ratios.len(), 2 + 2 * 4, "{imp:?}");
    for ratio in &imp.ratios {
        close(ratio.factor, 10.0, &ratio.figure);
    }
    assert_eq!(imp.ratios[2].figure, "x line at y = 0 mm: ISO 230-2 A");
}

fn refused(after: StageData, want: &str) {
    let e = verify(&VerifyOptions {
        spec: MachineSpec::paper(),
        before: None,
        after,
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains(want), "'{e}' lacks '{want}'");
}

#[test]
fn bad_input_is_refused_with_the_reason() {
    // One run: no estimator s.
    refused(StageData { verify: verify_rows(1.0), repeat: repeat_rows(&[x_line(), y_line()], 1, 1.0) }, "after, repeat runs: no axis line has at least 2 targets with 2 approaches from each direction (e.g. x line at y = 0 mm: target 0 mm has 1 approaches in + and 1 in − direction; each needs at least 2");
    // Ascending passes only: a direction is missing.
    let only_up: Vec<Measurement> = repeat_rows(&[x_line(), y_line()], 3, 1.0)
        .chunks(3)
        .step_by(2)
        .flatten()
        .cloned()
        .collect();
    refused(
        StageData {
            verify: verify_rows(1.0),
            repeat: only_up,
        },
        "in − direction; each needs at least 2",
    );
    // No y line.
    refused(
        StageData {
            verify: verify_rows(1.0),
            repeat: repeat_rows(&[x_line()], 3, 1.0),
        },
        "after, repeat runs: no y-axis line",
    );
    // NaN, a row without its target, a repeat row without its run, no rows.
    let mut nan = verify_rows(1.0);
    nan[1].measured_mm[1] = f64::NAN;
    refused(
        StageData {
            verify: nan,
            repeat: repeat_rows(&[x_line(), y_line()], 3, 1.0),
        },
        "after, verification measurements: line 3: a position is not a finite number",
    );
    let mut untargeted = verify_rows(1.0);
    untargeted[0].target_mm = None;
    refused(
        StageData {
            verify: untargeted,
            repeat: repeat_rows(&[x_line(), y_line()], 3, 1.0),
        },
        "line 2: every row needs its target",
    );
    let mut runless = repeat_rows(&[x_line(), y_line()], 3, 1.0);
    runless[4].run = None;
    refused(
        StageData {
            verify: verify_rows(1.0),
            repeat: runless,
        },
        "line 6: every row of the repeat runs needs its run",
    );
    refused(
        StageData {
            verify: Vec::new(),
            repeat: repeat_rows(&[x_line(), y_line()], 3, 1.0),
        },
        "after, verification measurements: no measurements",
    );
    // The before stage is checked as strictly and named.
    let e = verify(&VerifyOptions {
        spec: MachineSpec::paper(),
        before: Some(StageData {
            verify: verify_rows(1.0),
            repeat: Vec::new(),
        }),
        after: stage_data(1.0),
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("before, repeat runs: no measurements"), "{e}");
}

/// The page: every plot embedded (a map per state, a chart per axis line), outside text
/// escaped, no external resource.
#[test]
fn the_page_embeds_its_plots_and_escapes_text() {
    let mut spec = MachineSpec::paper();
    spec.name = "<b>&\"x\"".into();
    let r = verify(&VerifyOptions {
        spec: spec.clone(),
        before: Some(stage_data(10.0)),
        after: stage_data(1.0),
    })
    .unwrap();
    let page = html::render(
        &r,
        &spec,
        &[("after, verification".into(), "a<b>.csv".into())],
    )
    .unwrap();
    assert_eq!(page.matches("src=\"data:image/png;base64,").count(), 2 + 2);
    assert!(
        page.contains("machine '&lt;b&gt;&amp;&quot;x&quot;'") && !page.contains("<b>&"),
        "not escaped"
    );
    assert!(page.contains("<code>a&lt;b&gt;.csv</code>"));
    assert!(!page.contains("http") && !page.contains("<script"));
    // The summary row of the x line's A: 120 before, 12 after, 10x.
    assert!(page.contains("<tr><td>x line at y = 0 mm: ISO 230-2 accuracy A</td><td>120</td><td>12.0</td><td>10.0×</td></tr>"), "{}", &page[..3000]);
}
