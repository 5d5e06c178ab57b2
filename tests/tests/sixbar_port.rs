//! The benchmark's six-bar solve (`firmware/src/bin/bench/sixbar.rs`, host-sim's solver
//! ported to no_std f32 so that `cargo qemu-bench` can count it on the MCU) lands on the tool
//! point of host-sim's plant, and its built-in `paper` plant is host-sim's.
//!
//! Same link angles for both (the f32 ones, widened), so that the difference is the solvers'
//! alone: f32 against f64, and the f32 solver's looser stopping rule. Measured: within
//! 0.063 µm (bound 0.1 µm, the closed form's own f32 round-trip bound), on the paper plant
//! with and without its clearances and on a plant with random errors, over scattered
//! targets and along a path.

#[allow(dead_code)]
#[path = "../../firmware/src/bin/bench/sixbar.rs"]
mod sixbar;

use host_sim::plant::config::SixBarConfig;
use host_sim::plant::{PlantConfig, SixBar};
use kinematics_core::sixbar::SixBarDesign;
use kinematics_core::FiveBar;

/// host-sim's linkage description in the port's types.
fn params(c: &SixBarConfig) -> sixbar::SixBarParams {
    let d = c.design();
    let v = |a: [f64; 2]| [a[0] as f32, a[1] as f32];
    sixbar::SixBarParams {
        design: SixBarDesign {
            nominal: d.nominal.cast::<f32>(),
            platform_half_width_mm: d.platform_half_width_mm as f32,
            parallelogram_offsets_mm: d.parallelogram_offsets_mm.map(|arm| arm.map(v)),
            youngs_modulus_n_per_mm2: d.youngs_modulus_n_per_mm2 as f32,
            main_bar_section_mm2: d.main_bar_section_mm2 as f32,
            follower_bar_section_mm2: d.follower_bar_section_mm2 as f32,
        },
        errors: c.errors.map(|x| x as f32),
        pin_stiffness_n_per_mm: c.pin_stiffness_n_per_mm as f32,
        pin_clearance_mm: c.pin_clearance_mm as f32,
        bar_end_clearance_mm: c.bar_end_clearance_mm as f32,
        clearance_centring_ratio: c.clearance_centring_ratio as f32,
    }
}

#[test]
fn the_ports_paper_plant_is_host_sims() {
    // Debug text of every field: equal numbers print the same.
    let ported = sixbar::SixBarParams::paper();
    let host = params(&PlantConfig::paper().sixbar);
    assert_eq!(format!("{ported:?}"), format!("{host:?}"));
}

/// Worst distance (µm) between the two solvers' tool points along `targets` (solved in
/// order, both warm-starting from their previous solution), and the port's mean iterations.
fn worst_difference_um(cfg: &PlantConfig, targets: &[[f64; 2]]) -> (f64, f64) {
    let five = FiveBar::<f32>::paper_nominal();
    let mut host = SixBar::new(&cfg.sixbar);
    let mut port = sixbar::SixBar::new(&params(&cfg.sixbar));
    let (mut worst, mut iterations) = (0.0f64, 0u32);
    for t in targets {
        let theta = five
            .inverse([t[0] as f32, t[1] as f32], 0.0)
            .expect("target in the workspace");
        let h = host
            .solve([f64::from(theta[0]), f64::from(theta[1])])
            .expect("host-sim solves");
        let p = port.solve(theta).expect("the port solves");
        iterations += p.iterations;
        let d =
            (f64::from(p.tool_mm[0]) - h.tool_mm[0]).hypot(f64::from(p.tool_mm[1]) - h.tool_mm[1]);
        worst = worst.max(d * 1e3);
    }
    (worst, f64::from(iterations) / targets.len() as f64)
}

#[test]
fn the_port_lands_on_host_sims_tool_point() {
    // Scattered over the workspace (cold-ish starts) and along a 2 kHz path (warm starts).
    let grid: Vec<[f64; 2]> = (0..=5)
        .flat_map(|i| (0..=5).map(move |j| [162.132 + 20.0 * i as f64, -75.0 + 30.0 * j as f64]))
        .collect();
    let path: Vec<[f64; 2]> = (0..400)
        .map(|k| {
            let phase = std::f64::consts::PI * (k as f64 * 5e-4).powi(2) * 50.0;
            [212.132 + 20.0 * (phase.cos() - 1.0), 20.0 * phase.sin()]
        })
        .collect();
    let mut no_clearance = PlantConfig::paper();
    no_clearance.sixbar.pin_clearance_mm = 0.0;
    no_clearance.sixbar.bar_end_clearance_mm = 0.0;
    for (name, cfg) in [
        ("paper without clearances", no_clearance),
        ("paper", PlantConfig::paper()),
        (
            "random errors, seed 3",
            PlantConfig::paper().with_random_errors(3, 0.05, 0.0),
        ),
    ] {
        for (what, targets) in [("grid", &grid), ("path", &path)] {
            let (worst_um, iterations) = worst_difference_um(&cfg, targets);
            println!("{name}, {what}: port vs host-sim worst {worst_um:.4} um, {iterations:.2} iterations per solve");
            assert!(worst_um < 0.1, "{name}, {what}: {worst_um} um");
        }
    }
}
