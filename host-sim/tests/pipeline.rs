//! The calibration pipeline (measure → `full` fit → grid → command) in-process, on the shared
//! stand-in machine (`host_sim::machine::StandInMachine`: a five-bar with the paper's kind of
//! parameter errors plus a smooth distortion no five-bar describes, 1 µm instrument), through
//! `demo::calibrate`. Fresh random targets commanded through fit + grid must land within 5 µm
//! max and 2 µm RMS (issue 6's accuracy target), on hand-set errors and on randomly drawn ones.

use host_sim::demo::{calibrate, Calibrated, TARGET_MAX_UM, TARGET_RMS_UM};
use host_sim::machine::StandInMachine;
use kinematics_core::FiveBar;

fn check(cal: &Calibrated, label: &str) {
    let line: Vec<String> = cal.stages.iter().map(|s| format!("{} {:.1}/{:.2}", s.key, s.accuracy.max_um, s.accuracy.rms_um)).collect();
    eprintln!("{label}: max/rms µm: {}", line.join(", "));
    let get = |k: &str| cal.stages.iter().find(|s| s.key == k).unwrap().accuracy;
    let (nominal, full, gridded) = (get("nominal"), get("full"), get("full+grid"));
    assert!(nominal.max_um > 200.0 && full.max_um < nominal.max_um / 5.0, "{label}: {nominal:?} {full:?}");
    assert!(gridded.max_um < full.max_um && gridded.rms_um < full.rms_um, "{label}: {full:?} {gridded:?}");
    assert!(
        gridded.max_um <= TARGET_MAX_UM && gridded.rms_um <= TARGET_RMS_UM,
        "{label}: fit + grid: max {} µm, rms {} µm",
        gridded.max_um,
        gridded.rms_um
    );
}

#[test]
fn fit_then_grid_reaches_the_noise_floor() {
    let mut five_bar = FiveBar::<f64>::paper_nominal();
    five_bar.a_mm = 149.868;
    five_bar.b_mm = 150.06;
    five_bar.c_mm = 149.95;
    five_bar.d_mm = 150.09;
    five_bar.base_b0_mm = [0.12, -0.07];
    five_bar.encoder_offset_rad = [0.0015, -0.001];
    let mut machine = StandInMachine::new(five_bar, 1.0, 0.001, 11).unwrap();
    let cal = calibrate(&mut machine, 11).unwrap();
    check(&cal, "hand-set errors");
}

#[test]
fn randomly_drawn_machines_reach_the_noise_floor() {
    for seed in 1..=4 {
        let mut machine = StandInMachine::paper_like(100 + seed).unwrap();
        let cal = calibrate(&mut machine, seed).unwrap();
        check(&cal, &format!("paper-like machine, seed {}", 100 + seed));
    }
}
