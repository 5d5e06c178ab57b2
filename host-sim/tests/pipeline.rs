//! The calibration pipeline (measure → `full` fit → grid → command) on a stand-in machine, until
//! the plant lands: a five-bar with the paper's kind of parameter errors plus a smooth position-
//! dependent distortion no five-bar can describe (standing in for the six-bar's flexibility),
//! measured by a 1 µm instrument. Fresh random targets commanded through fit + grid must land
//! within 5 µm max and 2 µm RMS (issue 6's accuracy target).

use host_sim::fit::levenberg_marquardt::fit_full;
use host_sim::grid_build;
use host_sim::measurement_csv::Measurement;
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

struct StandIn {
    five_bar: FiveBar<f64>,
}

impl StandIn {
    /// Where the tool really is for encoder angles θ (mm).
    fn tool_mm(&self, th: [f64; 2]) -> [f64; 2] {
        let c = self.five_bar.forward(th, 0.0).unwrap();
        // ~40 µm smooth distortion over the workspace.
        let (u, v) = ((c[0] - 212.0) / 50.0, c[1] / 75.0);
        [c[0] + 0.03 * (1.3 * u).sin() * v + 0.01 * v * v, c[1] + 0.025 * (0.9 * v).sin() * u - 0.015 * u * u]
    }
}

fn measure(m: &StandIn, cal: &Calibration<'_>, targets: &[[f64; 2]], rng: &mut ChaCha8Rng) -> Vec<Measurement> {
    let noise = Normal::new(0.0, 0.001).unwrap();
    targets
        .iter()
        .map(|&t| {
            let th = cal.command_rad([t[0] as f32, t[1] as f32], 0.05).unwrap();
            let th = [th[0] as f64, th[1] as f64];
            let c = m.tool_mm(th);
            Measurement {
                theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                measured_mm: [c[0] + noise.sample(rng), c[1] + noise.sample(rng)],
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: 0,
            }
        })
        .collect()
}

/// (max, rms) µm of the true tool position vs target over fresh random targets.
fn verify(m: &StandIn, cal: &Calibration<'_>, rng: &mut ChaCha8Rng) -> (f64, f64) {
    let e: Vec<f64> = (0..400)
        .map(|_| {
            let t = [rng.random_range(165.0..260.0), rng.random_range(-75.0..75.0)];
            let th = cal.command_rad([t[0] as f32, t[1] as f32], 0.05).unwrap();
            let c = m.tool_mm([th[0] as f64, th[1] as f64]);
            (c[0] - t[0]).hypot(c[1] - t[1]) * 1e3
        })
        .collect();
    host_sim::fit::evaluate::max_rms(&e)
}

#[test]
fn fit_then_grid_reaches_the_noise_floor() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut five_bar = FiveBar::<f64>::paper_nominal();
    five_bar.a_mm = 149.868;
    five_bar.b_mm = 150.06;
    five_bar.c_mm = 149.95;
    five_bar.d_mm = 150.09;
    five_bar.base_b0_mm = [0.12, -0.07];
    five_bar.encoder_offset_rad = [0.0015, -0.001];
    let machine = StandIn { five_bar };
    let nominal = FiveBar::<f64>::paper_nominal();

    let bare = Calibration { model: nominal.cast(), grid: None };
    let (max0, _) = verify(&machine, &bare, &mut rng);

    // Step 1: 40 random poses, full fit.
    let poses: Vec<[f64; 2]> = (0..40).map(|_| [rng.random_range(165.0..260.0), rng.random_range(-75.0..75.0)]).collect();
    let fit = fit_full(&measure(&machine, &bare, &poses, &mut rng), &nominal, &[]).unwrap();
    let fitted = Calibration { model: fit.model.cast(), grid: None };
    let (max1, _) = verify(&machine, &fitted, &mut rng);

    // Step 2: the 5 mm grid commanded with the fitted model.
    let nodes: Vec<[f64; 2]> = (0..31).flat_map(|j| (0..20).map(move |i| [165.0 + 5.0 * i as f64, -75.0 + 5.0 * j as f64])).collect();
    let built = grid_build::build(&fit.model, &measure(&machine, &fitted, &nodes, &mut rng), 5.0).unwrap();
    let cal = Calibration::from_grid(CorrectionGrid::parse(&built.image).unwrap());
    let (max2, rms2) = verify(&machine, &cal, &mut rng);
    eprintln!("max error: nominal {max0:.1} µm, fitted {max1:.1} µm, fit + grid {max2:.2} µm (rms {rms2:.2} µm)");
    assert!(max0 > 200.0 && max1 < max0 / 5.0, "{max0} {max1}");
    assert!(max2 < 5.0 && rms2 < 2.0, "fit + grid: max {max2} µm, rms {rms2} µm");
}
