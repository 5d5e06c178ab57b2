//! The one Levenberg–Marquardt (`host_sim::numeric::lm`, used by `fit --method full` and by
//! every fit of `diagnose`), started far from the optimum: the accepted cost never increases,
//! it converges to the known optimum, and it would fail if the solver accepted any finite step.

use host_sim::calib::fit::full::fit_full;
use host_sim::calib::fit::params::{to_vector, NAMES};
use host_sim::io::measurement_csv::Measurement;
use host_sim::numeric::{levenberg_marquardt, LmFit, LmOptions, Residuals, Stop};
use kinematics_core::FiveBar;
use nalgebra::DVector;

/// Rosenbrock's valley as least squares: r = (10·(y − x²), 1 − x), optimum (1, 1), cost 0.
struct Rosenbrock;

impl Residuals for Rosenbrock {
    fn n_params(&self) -> usize {
        2
    }
    fn residuals(&self, p: &[f64]) -> Option<DVector<f64>> {
        Some(DVector::from_vec(vec![
            10.0 * (p[1] - p[0] * p[0]),
            1.0 - p[0],
        ]))
    }
    fn fd_step(&self, _k: usize) -> f64 {
        1e-7
    }
}

fn assert_strictly_decreasing(fit: &LmFit, what: &str) {
    let h = &fit.cost_history;
    assert!(h.len() >= 2, "{what}: no accepted step");
    for (k, w) in h.windows(2).enumerate() {
        assert!(
            w[1] < w[0],
            "{what}: cost rose at accepted step {}: {} -> {}",
            k + 1,
            w[0],
            w[1]
        );
    }
    assert_eq!(
        *h.last().unwrap(),
        fit.cost,
        "{what}: the history ends at the reported cost"
    );
}

#[test]
fn rosenbrock_from_the_classic_start() {
    // From (−1.2, 1) the undamped Gauss–Newton step lands at (1, −3.84), cost 2343 against the
    // start's 24.2: an LM that accepted any finite step would show that rise in its history.
    let start = [-1.2, 1.0];
    let fit = levenberg_marquardt(&Rosenbrock, &start, &[0, 1], &LmOptions::default()).unwrap();
    assert_strictly_decreasing(&fit, "Rosenbrock");
    assert!(
        fit.rejected_steps > 0,
        "the overshooting Gauss–Newton steps must have been refused"
    );
    assert!(
        (fit.p[0] - 1.0).abs() < 1e-9 && (fit.p[1] - 1.0).abs() < 1e-9,
        "{:?} ({:?})",
        fit.p,
        fit.stop
    );
    assert!(fit.cost < 1e-20, "{}", fit.cost);
    assert_ne!(fit.stop, Stop::MaxIterations);
    // Only the free parameters move.
    let held = levenberg_marquardt(&Rosenbrock, &start, &[1], &LmOptions::default()).unwrap();
    assert_eq!(held.p[0], -1.2);
    assert!((held.p[1] - 1.44).abs() < 1e-9, "{:?}", held.p);
}

/// A linear problem with a known covariance: r = A·p − b, (AᵀA)⁻¹ exactly.
struct Line {
    x: Vec<f64>,
    y: Vec<f64>,
}

impl Residuals for Line {
    fn n_params(&self) -> usize {
        2
    }
    fn residuals(&self, p: &[f64]) -> Option<DVector<f64>> {
        Some(DVector::from_iterator(
            self.x.len(),
            self.x.iter().zip(&self.y).map(|(x, y)| p[0] + p[1] * x - y),
        ))
    }
    fn fd_step(&self, _k: usize) -> f64 {
        1e-3
    }
}

#[test]
fn linear_fit_and_its_covariance() {
    let x: Vec<f64> = (0..10).map(f64::from).collect();
    let y: Vec<f64> = x
        .iter()
        .map(|x| 2.0 - 0.5 * x + if (*x as i32) % 2 == 0 { 0.1 } else { -0.1 })
        .collect();
    let fit = levenberg_marquardt(
        &Line { x: x.clone(), y },
        &[100.0, 100.0],
        &[0, 1],
        &LmOptions::default(),
    )
    .unwrap();
    assert_strictly_decreasing(&fit, "line");
    // Normal equations by hand: n = 10, Σx = 45, Σx² = 285.
    let (n, sx, sxx) = (10.0, 45.0, 285.0);
    let det = n * sxx - sx * sx;
    let want = [sxx / det, n / det];
    for (k, w) in want.iter().enumerate() {
        let got = fit.std_dev(k, 1.0).unwrap().powi(2);
        assert!((got - w).abs() < 1e-9 * w, "variance {k}: {got} vs {w}");
    }
    // Alternating ±0.1 about the line: the slope and intercept barely move.
    assert!(
        (fit.p[1] + 0.5).abs() < 0.03 && (fit.p[0] - 2.0).abs() < 0.2,
        "{:?}",
        fit.p
    );
    assert_eq!(fit.rank(), 2);
}

/// Measurements of `truth` at poses commanded with the nominal model (noise-free).
fn measure(truth: &FiveBar<f64>) -> Vec<Measurement> {
    let nominal = FiveBar::<f64>::paper_nominal();
    let mut data = Vec::new();
    for i in 0..8 {
        for j in 0..6 {
            let t = [167.0 + 13.0 * f64::from(i), -70.0 + 28.0 * f64::from(j)];
            let th = nominal.inverse(t, 0.05).unwrap();
            data.push(Measurement {
                theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                measured_mm: truth.forward(th, 0.0).unwrap(),
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: data.len() + 2,
            });
        }
    }
    data
}

#[test]
fn five_bar_fit_from_millimetres_and_milliradians_away() {
    // Links 2–3 mm off, B0 and A0 1.5–2.5 mm off, encoder offsets 6–8 mrad (0.35–0.45°): about
    // 20 times the paper machine's errors.
    let mut truth = FiveBar::<f64>::paper_nominal();
    truth.a_mm = 152.4;
    truth.b_mm = 147.1;
    truth.c_mm = 153.0;
    truth.d_mm = 148.2;
    truth.base_b0_mm = [1.8, -2.5];
    truth.base_a0_mm = [-1.5, 2.0];
    truth.encoder_offset_rad = [0.008, -0.006];
    let data = measure(&truth);
    let f = fit_full(&data, &FiveBar::paper_nominal(), &[]).unwrap();
    assert!(
        f.identifiability.fixed.is_empty(),
        "{:?}",
        f.identifiability.fixed
    );
    assert_strictly_decreasing(&f.lm, "five-bar");
    assert!(
        f.lm.cost_history[0] > 1e6 * f.lm.cost_history[1..].last().unwrap().max(1e-30),
        "{:?}",
        f.lm.cost_history
    );
    let (got, want) = (to_vector(&f.model), to_vector(&truth));
    for k in 0..NAMES.len() {
        assert!(
            (got[k] - want[k]).abs() < 1e-7,
            "{}: {} vs {} after {:?}",
            NAMES[k],
            got[k],
            want[k],
            f.lm.stop
        );
    }
    assert_ne!(f.lm.stop, Stop::MaxIterations);
}
