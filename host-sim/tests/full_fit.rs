//! `fit --method full` on synthetic five-bars: parameters recovered within their standard
//! deviations, and confounded parameters detected and held, not fitted.

use host_sim::calib::fit::blunders::{
    fit_full_robust, RejectOptions, RobustFit, DEFAULT_REJECT_SIGMA,
};
use host_sim::calib::fit::full::{fit_full, leave_one_out_exact_um, leave_one_out_linearised_um};
use host_sim::calib::fit::params::{to_vector, NAMES};
use host_sim::io::measurement_csv::Measurement;
use kinematics_core::FiveBar;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn truth() -> FiveBar<f64> {
    let mut m = FiveBar::<f64>::paper_nominal();
    m.a_mm = 149.92;
    m.b_mm = 150.07;
    m.c_mm = 149.96;
    m.d_mm = 150.11;
    m.base_b0_mm = [0.08, -0.05];
    m.encoder_offset_rad = [0.0012, -0.0007];
    m
}

/// Measurements of `truth` at targets commanded with the nominal model, noise σ (mm).
fn measure(
    truth: &FiveBar<f64>,
    targets: &[[f64; 2]],
    sigma_mm: f64,
    seed: u64,
) -> Vec<Measurement> {
    let nominal = FiveBar::<f64>::paper_nominal();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma_mm).unwrap();
    targets
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let th = nominal.inverse(t, 0.05).unwrap();
            let c = truth.forward(th, 0.0).unwrap();
            Measurement {
                theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                measured_mm: [c[0] + noise.sample(&mut rng), c[1] + noise.sample(&mut rng)],
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: i + 2,
            }
        })
        .collect()
}

fn random_targets(n: usize, seed: u64) -> Vec<[f64; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            [
                rng.random_range(162.0..262.0),
                rng.random_range(-75.0..75.0),
            ]
        })
        .collect()
}

#[test]
fn recovers_perturbed_parameters_within_std_dev() {
    let t = truth();
    let data = measure(&t, &random_targets(60, 1), 0.001, 2);
    let f = fit_full(&data, &FiveBar::paper_nominal(), &[]).unwrap();
    assert!(
        f.identifiability.fixed.is_empty(),
        "{:?}",
        f.identifiability.fixed
    );
    let (got, want) = (to_vector(&f.model), to_vector(&t));
    let mut worst_z: f64 = 0.0;
    for k in 0..NAMES.len() {
        let sd = f.std_dev[k].unwrap();
        assert!(sd > 0.0 && sd.is_finite());
        let z = (got[k] - want[k]) / sd;
        worst_z = worst_z.max(z.abs());
        // 4σ: eight parameters, a false alarm is ~5e-4.
        assert!(
            z.abs() < 4.0,
            "{}: got {} want {} sd {sd} (z = {z:.2})",
            NAMES[k],
            got[k],
            want[k]
        );
    }
    // The estimated residual σ matches the noise put in.
    assert!((f.sigma_mm - 0.001).abs() < 0.0003, "sigma {}", f.sigma_mm);
    // And without noise the fit is exact.
    let exact = fit_full(
        &measure(&t, &random_targets(20, 3), 1e-12, 4),
        &FiveBar::paper_nominal(),
        &[],
    )
    .unwrap();
    let (got, want) = (to_vector(&exact.model), to_vector(&t));
    for k in 0..NAMES.len() {
        assert!(
            (got[k] - want[k]).abs() < 1e-7,
            "{}: {} vs {}",
            NAMES[k],
            got[k],
            want[k]
        );
    }
}

/// With motor 2 never moved, only the elbow B is seen: d, its encoder offset and the base offset
/// B0 trade off. The check must name that and hold two of them, and still fit the rest.
#[test]
fn flags_confounded_parameters_on_degenerate_data() {
    let t = truth();
    let nominal = FiveBar::<f64>::paper_nominal();
    // Motor 2 fixed at -45°, motor 1 swept.
    let data: Vec<Measurement> = (0..15)
        .map(|k| {
            let th = [
                (30.0 + 2.0 * k as f64).to_radians(),
                (-45.0f64).to_radians(),
            ];
            let c = t.forward(th, 0.0).unwrap();
            Measurement {
                theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                measured_mm: c,
                target_mm: None,
                dir: None,
                run: None,
                t_s: None,
                line: k + 2,
            }
        })
        .collect();
    let f = fit_full(&data, &nominal, &[]).unwrap();
    let fixed: Vec<&str> = f
        .identifiability
        .fixed
        .iter()
        .map(|(k, _)| NAMES[*k])
        .collect();
    assert_eq!(
        f.identifiability.rank_all, 6,
        "{:?}",
        f.identifiability.singular_values_rel
    );
    // Ten parameters, rank 6: the four base coordinates (A0 and B0) are held at nominal.
    assert_eq!(
        fixed,
        vec![
            "base_b0_y_mm",
            "base_b0_x_mm",
            "base_a0_y_mm",
            "base_a0_x_mm"
        ],
        "{:?}",
        f.identifiability.fixed
    );
    let why = &f.identifiability.fixed[0].1;
    assert!(
        why.contains("d_mm") || why.contains("encoder_offset_2_rad"),
        "{why}"
    );
    assert!(
        f.std_dev[4].is_none()
            && f.std_dev[5].is_none()
            && f.std_dev[8].is_none()
            && f.std_dev[9].is_none()
    );
    assert!(f.std_dev[3].unwrap().is_finite());
    // The free ones reproduce the data exactly (the elbow B is right even if d is not true d).
    let r = host_sim::calib::fit::params::residuals_mm(&f.model, &data).unwrap();
    assert!(r.amax() < 1e-6, "{}", r.amax());
}

#[test]
fn refuses_fewer_points_than_parameters() {
    let data = measure(&truth(), &random_targets(4, 5), 0.001, 6);
    let err = format!(
        "{:#}",
        fit_full(&data, &FiveBar::paper_nominal(), &[]).unwrap_err()
    );
    assert!(err.contains("4 points give 8 equations"), "{err}");
}

/// The blunder test's data: 60 rows of `truth()` with a 1 µm instrument.
fn clean_60() -> Vec<Measurement> {
    measure(&truth(), &random_targets(60, 11), 0.001, 12)
}

/// Rows 7 (0.5 mm off in x), 23 (0.1 mm off in y) and 41 (x and y swapped): 1-based.
fn with_three_blunders() -> Vec<Measurement> {
    let mut d = clean_60();
    d[6].measured_mm[0] += 0.5;
    d[22].measured_mm[1] += 0.1;
    d[40].measured_mm = [d[40].measured_mm[1], d[40].measured_mm[0]];
    d
}

fn robust(
    data: &[Measurement],
    reject_sigma: f64,
) -> Result<RobustFit, host_sim::calib::CalibError> {
    fit_full_robust(
        data,
        &FiveBar::paper_nominal(),
        &[],
        &RejectOptions {
            reject_sigma,
            instrument_sigma_um: 1.0,
        },
    )
}

#[test]
fn blunder_test_names_exactly_the_planted_rows_and_recovers_the_clean_fit() {
    let clean = robust(&clean_60(), DEFAULT_REJECT_SIGMA).unwrap();
    let report = clean.report.as_ref().unwrap();
    assert!(
        report.rejected.is_empty() && report.fits == 1 && report.settled,
        "clean data lost rows: {report:?}"
    );
    assert_eq!(clean.kept.len(), 60);

    let got = robust(&with_three_blunders(), DEFAULT_REJECT_SIGMA).unwrap();
    let report = got.report.as_ref().unwrap();
    let rows: Vec<usize> = report.rejected.iter().map(|r| r.row).collect();
    assert_eq!(rows, [7, 23, 41], "{report:?}");
    assert!(report.settled, "{report:?}");
    // Each named with its file line and its residual against the fit without it.
    let by_row = |row: usize| report.rejected.iter().find(|r| r.row == row).unwrap();
    assert_eq!(by_row(7).line, 8);
    assert!(
        (by_row(7).residual_um - 500.0).abs() < 10.0,
        "{:?}",
        by_row(7)
    );
    assert!(
        (by_row(23).residual_um - 100.0).abs() < 10.0,
        "{:?}",
        by_row(23)
    );
    assert!(by_row(41).residual_um > 1e5, "{:?}", by_row(41));
    assert!(
        report
            .rejected
            .iter()
            .all(|r| r.sigma_units > report.threshold_sigma),
        "{report:?}"
    );
    assert_eq!(got.kept.len(), 57);
    // The parameters agree with the clean fit's within one of its standard deviations.
    let (a, b) = (to_vector(&got.fit.model), to_vector(&clean.fit.model));
    for k in 0..NAMES.len() {
        let sd = clean.fit.std_dev[k].unwrap();
        assert!(
            (a[k] - b[k]).abs() < sd,
            "{}: {} vs clean {} (sd {sd})",
            NAMES[k],
            a[k],
            b[k]
        );
    }
    // Off, the blunders stay in and spoil the fit.
    let off = robust(&with_three_blunders(), 0.0).unwrap();
    assert!(off.report.is_none() && off.kept.len() == 60);
    assert!(
        off.fit.sigma_mm > 100.0 * clean.fit.sigma_mm,
        "{} vs {}",
        off.fit.sigma_mm,
        clean.fit.sigma_mm
    );
}

#[test]
fn blunder_test_refuses_more_than_the_allowed_fraction() {
    // 60 rows allow 6; plant 8, each 0.3 mm off.
    let mut d = clean_60();
    for i in [2, 9, 15, 22, 30, 37, 44, 51] {
        d[i].measured_mm[0] += 0.3;
    }
    let err = format!("{}", robust(&d, DEFAULT_REJECT_SIGMA).unwrap_err());
    assert!(
        err.contains("8 of 60 rows") && err.contains("the data or the model are wrong"),
        "{err}"
    );
    assert!(
        err.contains("(rows 3, 10, 16, 23, 31, 38, 45, 52)"),
        "{err}"
    );
    // Six such rows are the most 60 rows may lose: fitted, and exactly those named.
    let mut d = clean_60();
    for i in [2, 9, 15, 22, 30, 37] {
        d[i].measured_mm[0] += 0.3;
    }
    let got = robust(&d, DEFAULT_REJECT_SIGMA).unwrap();
    let rows: Vec<usize> = got.report.unwrap().rejected.iter().map(|r| r.row).collect();
    assert_eq!(rows, [3, 10, 16, 23, 31, 38]);
    // A threshold that is no number of σ is refused.
    for k in [-1.0, f64::NAN, 1.0] {
        assert!(robust(&clean_60(), k).is_err(), "{k}");
    }
}

/// The hat-matrix leave-one-out residuals (used above 200 points) agree with
/// exact refits on a small set.
#[test]
fn linearised_leave_one_out_matches_exact_refits() {
    let data = measure(&truth(), &random_targets(40, 21), 0.001, 22);
    let nominal = FiveBar::<f64>::paper_nominal();
    let f = fit_full(&data, &nominal, &[]).unwrap();
    let lin = leave_one_out_linearised_um(&f);
    let exact = leave_one_out_exact_um(&data, &nominal, &[], &mut |_, _| {});
    let mut worst: f64 = 0.0;
    for (i, (l, e)) in lin.iter().zip(&exact).enumerate() {
        let (l, e) = (l.unwrap(), e.unwrap());
        worst = worst.max((l - e).abs());
        assert!(l > 0.0 && e > 0.0, "point {}: {l} vs {e}", i + 1);
    }
    // Seen: 6.4e-6 µm on residuals of 0.25–3.9 µm. The bound, 1e-3 µm (0.1 % of the noise),
    // leaves room for the exact refits' own convergence tolerance.
    eprintln!("linearised vs exact leave-one-out, 40 points: worst difference {worst:.2e} µm");
    assert!(worst < 1e-3, "worst |linearised − exact| = {worst} µm");
}

/// An instrument better than the five-bar's own error on the six-bar (the `paper` plant read at
/// `plan`'s 40 D-optimal poses with σ = 0.1 µm): the good rows' residuals are the model error,
/// heavy-tailed and largest at the high-leverage edge poses. The test statistic is studentized
/// (a high-leverage row is not judged larger than its spread) and the scale follows the upper
/// quantile of the residuals, so the fit is made, not refused (before: "5 of 40 rows ... the
/// data or the model are wrong"), and at most one row is named.
#[test]
fn a_precise_instrument_on_the_six_bar_is_no_flood_of_blunders() {
    use host_sim::calib::machine::PlantMachine;
    use host_sim::calib::measure::{measure_visits, rows};
    use host_sim::calib::pipeline::Approach;
    use host_sim::calib::plan::{plan, PlanOptions};
    use host_sim::machine_spec::MachineSpec;
    use kinematics_core::Calibration;
    let spec = MachineSpec {
        instrument_sigma_um: 0.1,
        ..MachineSpec::paper()
    };
    let p = plan(&PlanOptions::new(spec.clone(), 1)).unwrap();
    let nominal = Calibration {
        model: spec.nominal.cast(),
        grid: None,
    };
    for sigma_um in [0.0, 0.1, 0.3] {
        let mut machine = PlantMachine::by_name("paper", Some(sigma_um), 11).unwrap();
        let data = rows(
            &measure_visits(
                &mut machine,
                &nominal,
                &p.identify,
                Approach::Positive,
                &spec,
                &mut 0,
            )
            .unwrap(),
        );
        let got = fit_full_robust(
            &data,
            &spec.nominal,
            &[],
            &RejectOptions {
                reject_sigma: DEFAULT_REJECT_SIGMA,
                instrument_sigma_um: 0.1,
            },
        )
        .unwrap_or_else(|e| panic!("σ = {sigma_um} µm: {e}"));
        let report = got.report.unwrap();
        eprintln!(
            "σ = {sigma_um} µm: {} rejected, scale {} µm ({:?})",
            report.rejected.len(),
            report.sigma_um,
            report.sigma_source
        );
        assert!(report.rejected.len() <= 1, "σ = {sigma_um} µm: {report:?}");
    }
}

/// The instrument anywhere: readings of `truth` moved by `frame` (machine → instrument).
fn through(data: &[Measurement], frame: host_sim::numeric::Rigid2) -> Vec<Measurement> {
    data.iter()
        .map(|m| Measurement {
            measured_mm: frame.apply(m.measured_mm),
            ..m.clone()
        })
        .collect()
}

fn fit_registered(
    data: &[Measurement],
    method: host_sim::calib::fit::Method,
) -> host_sim::calib::fit::FitOutcome {
    use host_sim::calib::fit::{evaluate::Criterion, fit, FitOptions, FrameMode, Points};
    fit(
        data,
        &FitOptions {
            method,
            criterion: Criterion::Measured,
            points: Points::All,
            fixed: vec![],
            leave_one_out: false,
            reject_sigma: DEFAULT_REJECT_SIGMA,
            frame: FrameMode::Register,
            spec: host_sim::machine_spec::MachineSpec::paper(),
        },
        &mut |_| {},
    )
    .unwrap()
}

/// A tracker metres away and at any angle: `full` returns the same machine-frame model as
/// with the tracker at the machine's origin, and the frame it stood in. The truth satisfies
/// the convention (A0 nominal, mean encoder offset nominal), so both are recovered to the
/// noise; the frame's standard deviations cover the errors.
#[test]
fn full_registers_a_tracker_anywhere() {
    use host_sim::calib::fit::Method;
    use host_sim::numeric::Rigid2;
    let mut t = truth();
    t.encoder_offset_rad = [0.0012, -0.0012]; // mean 0: the convention's
    let data = measure(&t, &random_targets(60, 11), 0.001, 12);
    let at_home = fit_registered(&data, Method::Full);
    for frame in [
        Rigid2 {
            rotation_rad: 0.35f64.to_radians(),
            offset_mm: [12.5, -4.0],
        },
        Rigid2 {
            rotation_rad: 137f64.to_radians(),
            offset_mm: [2500.0, -1800.0],
        },
        Rigid2 {
            rotation_rad: -3.0,
            offset_mm: [-7000.0, 350.0],
        },
    ] {
        let o = fit_registered(&through(&data, frame), Method::Full);
        let (p, q, h) = (
            to_vector(&o.model),
            to_vector(&t),
            to_vector(&at_home.model),
        );
        for k in 0..NAMES.len() {
            // 1 nm / 1 nrad: the same fit, whatever the frame.
            assert!(
                (p[k] - h[k]).abs() < 1e-6,
                "{}: {} vs {}",
                NAMES[k],
                p[k],
                h[k]
            );
            let sd = o
                .std_dev
                .get(&host_sim::calib::fit::params::std_dev_entry(k, 1.0).0);
            if let Some(sd) = sd {
                let sd = if k == 6 || k == 7 {
                    sd.to_radians()
                } else {
                    *sd
                };
                assert!(
                    (p[k] - q[k]).abs() < 4.0 * sd,
                    "{}: {} vs {} ± {sd}",
                    NAMES[k],
                    p[k],
                    q[k]
                );
            }
        }
        assert_eq!(o.model.base_a0_mm, [0.0, 0.0], "the gauge's A0");
        let f = o.frame.unwrap();
        let sd = f.std_dev.unwrap();
        let dr = (f.to_instrument.rotation_rad - frame.rotation_rad).abs();
        assert!(
            dr < 4.0 * sd[0] && dr < 1e-4,
            "rotation {dr} rad ± {}",
            sd[0]
        );
        for k in 0..2 {
            let d = (f.to_instrument.offset_mm[k] - frame.offset_mm[k]).abs();
            assert!(
                d < 4.0 * sd[1 + k] + 1e-6,
                "offset {k}: {d} mm ± {}",
                sd[1 + k]
            );
        }
        assert!(o.summary.max_err_um < 5.0, "{}", o.summary.max_err_um);
        // The links-only fits register too (with the nominal model's frame) and stay
        // plausible.
        let ls = fit_registered(&through(&data, frame), Method::Ls);
        assert!(
            (ls.model.b_mm - 150.0).abs() < 1.0,
            "ls b {}",
            ls.model.b_mm
        );
        assert!(ls.frame.is_some());
    }
}

/// What the readings cannot tell apart: a machine whose A0 bearing sits 0.4 mm off its
/// drawing and whose two encoder zeros are both 0.05° off, read by an instrument at the
/// machine's origin, gives exactly the readings of the drawing's machine read by an instrument
/// shifted and turned by that much. The fit returns the same model for both (A0 nominal, the
/// mean offset nominal: the convention) and puts the difference in the frame; the offsets'
/// difference and B0 − A0 are identified.
#[test]
fn a_common_shift_and_rotation_of_the_machine_is_the_frame() {
    use host_sim::calib::fit::Method;
    use host_sim::numeric::Rigid2;
    let mut t = truth();
    t.encoder_offset_rad = [0.0012, -0.0012];
    let psi = 0.05f64.to_radians();
    let mut moved = t;
    moved.base_a0_mm = [0.4, -0.3];
    moved.base_b0_mm = Rigid2 {
        rotation_rad: psi,
        offset_mm: [0.0, 0.0],
    }
    .rotate(t.base_b0_mm);
    moved.encoder_offset_rad = t.encoder_offset_rad.map(|o| o + psi);
    let targets = random_targets(60, 21);
    let a = fit_registered(&measure(&moved, &targets, 0.0, 22), Method::Full);
    let b = fit_registered(&measure(&t, &targets, 0.0, 22), Method::Full);
    let (p, q) = (to_vector(&a.model), to_vector(&b.model));
    for k in 0..NAMES.len() {
        assert!(
            (p[k] - q[k]).abs() < 1e-7,
            "{}: {} vs {}",
            NAMES[k],
            p[k],
            q[k]
        );
    }
    let (fa, fb) = (
        a.frame.unwrap().to_instrument,
        b.frame.unwrap().to_instrument,
    );
    assert!(
        (fa.rotation_rad - fb.rotation_rad - psi).abs() < 1e-9,
        "{fa:?} {fb:?}"
    );
    assert!((fa.offset_mm[0] - 0.4).abs() < 1e-6 && (fa.offset_mm[1] + 0.3).abs() < 1e-6);
}
