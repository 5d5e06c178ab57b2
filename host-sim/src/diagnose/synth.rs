//! Synthetic measurements with hidden effects, for testing the diagnosis against a truth it does
//! not share code with (the six-bar plant, `calib::measure`, is the other source).
//!
//! Why here and not in the test file: the CLI tests, the unit tests and the studies
//! (`benches/diagnose_study.rs`) all need the same generator; it is small and has no other
//! dependency. Poses are on the paper machine ([`MachineSpec::paper`]).
//!
//! The truth is a five-bar (the nominal machine plus per-effect perturbations), commanded with
//! the *nominal* inverse kinematics at targets on the paper's 5 mm grid or at random targets,
//! each motor approaching from a random direction. Where the physics allows, effects are
//! generated in a form different from the diagnosis library so the tests are not circular:
//! * `link_stretch` comes from a spring model — the loop preload force grows with the distal
//!   angle ψ away from its mean over the poses, with a quadratic term, and stretches b and c
//!   through their compliances — while the library uses a basis linear in cos ψ;
//! * the frame rotates about an instrument origin away from A0 (library: about A0, plus offset);
//! * a gear-tooth cyclic error (in no library) adds `A·sin(N·θ_j + φ)` to one motor's link angle;
//! * an instrument drift (in no library) adds a reading offset growing linearly with time.
//!
//! Backlash, encoder offsets, link lengths, base offset and scale have one physical form; the
//! generator uses it. Noise: Gaussian, σ per axis. Cost: one IK and one or two FK per pose.

use crate::effect::PhysicalEffect;
use crate::io::measurement_csv::Measurement;
use crate::machine_spec::MachineSpec;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A gear-tooth (or any periodic) error of one motor.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cyclic {
    /// 0 or 1.
    pub motor: usize,
    /// Cycles per motor revolution.
    pub cycles: f64,
    pub amplitude_urad: f64,
    pub phase_rad: f64,
}

/// The hidden truth. All zero = the nominal machine.
#[derive(Clone, Debug, Default)]
pub struct Truth {
    pub link_delta_um: [f64; 4],
    pub encoder_offset_urad: [f64; 2],
    pub base_offset_um: [f64; 2],
    /// Lost motion per motor (µrad); the link lags the motor by half of it.
    pub backlash_urad: [f64; 2],
    /// Spring model: stretch of b and c (µm) per radian of ψ away from its mean.
    pub stretch_um_per_rad: [f64; 2],
    /// Quadratic and cubic (hardening spring) terms of the loop preload, per radian of ψ away
    /// from its mean.
    pub stretch_quadratic_per_rad: f64,
    pub stretch_cubic_per_rad2: f64,
    /// Instrument offset x, y (µm) and rotation (µrad) about `frame_origin_mm`.
    pub frame: [f64; 3],
    pub frame_origin_mm: [f64; 2],
    pub scale_ppm: f64,
    /// Transmission ratio error (ppm) about the mean motor angle of the poses.
    pub gear_ppm: [f64; 2],
    pub cyclic: Option<Cyclic>,
    /// Instrument drift (thermal), µm per second of `t_s`, x and y (in no library).
    pub drift_um_per_s: [f64; 2],
    pub noise_um: f64,
}

/// Where the poses are (on the paper machine).
#[derive(Clone, Copy, Debug)]
pub enum Poses {
    /// The paper's 5 mm grid over x ∈ [162.132, 262.132], y ∈ [−75, 75] (651 poses).
    Grid5mm,
    /// Uniform random targets in the same rectangle.
    Random(usize),
    /// The paper's Table I targets (corners, side midpoints, centre).
    Table1,
}

fn sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random_bool(0.5) {
        1.0
    } else {
        -1.0
    }
}

/// A random magnitude in [lo, hi] with a random sign.
fn mag(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    sign(rng) * rng.random_range(lo..hi)
}

impl Truth {
    /// One library effect switched on with a random magnitude well above 2 µm noise; effects the
    /// diagnosis library does not name have no random form here (an error naming the effect).
    pub fn add_random(&mut self, effect: PhysicalEffect, rng: &mut ChaCha8Rng) -> Result<(), String> {
        match effect {
            PhysicalEffect::LinkLengths => self.link_delta_um = [(); 4].map(|_| mag(rng, 20.0, 100.0)),
            PhysicalEffect::EncoderOffset => self.encoder_offset_urad = [(); 2].map(|_| mag(rng, 100.0, 400.0)),
            PhysicalEffect::BaseOffset => self.base_offset_um = [(); 2].map(|_| mag(rng, 30.0, 120.0)),
            PhysicalEffect::Backlash => self.backlash_urad = [(); 2].map(|_| rng.random_range(60.0..200.0)),
            PhysicalEffect::LinkStretch => {
                self.stretch_um_per_rad = [(); 2].map(|_| mag(rng, 40.0, 120.0));
                // A hardening loop spring: without the cubic term the stretch is, on the rhombus,
                // exactly link_lengths + encoder_offset (see effects.rs) and not a test of it.
                self.stretch_quadratic_per_rad = 3.0;
                self.stretch_cubic_per_rad2 = 3.0;
            }
            PhysicalEffect::Frame => {
                self.frame = [mag(rng, 30.0, 120.0), mag(rng, 30.0, 120.0), mag(rng, 100.0, 400.0)];
                self.frame_origin_mm = [rng.random_range(-500.0..500.0), rng.random_range(-500.0..500.0)];
            }
            PhysicalEffect::Scale => self.scale_ppm = mag(rng, 150.0, 500.0),
            PhysicalEffect::GearRatio => self.gear_ppm = [(); 2].map(|_| mag(rng, 300.0, 1000.0)),
            other => return Err(format!("{other} is not in the diagnosis library: no random form")),
        }
        Ok(())
    }
}

impl Truth {
    /// The same truth with every effect magnitude multiplied by `f` (noise unchanged).
    pub fn scaled(&self, f: f64) -> Truth {
        let mut t = self.clone();
        t.link_delta_um = t.link_delta_um.map(|v| v * f);
        t.encoder_offset_urad = t.encoder_offset_urad.map(|v| v * f);
        t.base_offset_um = t.base_offset_um.map(|v| v * f);
        t.backlash_urad = t.backlash_urad.map(|v| v * f);
        t.stretch_um_per_rad = t.stretch_um_per_rad.map(|v| v * f);
        t.frame = t.frame.map(|v| v * f);
        t.scale_ppm *= f;
        t.gear_ppm = t.gear_ppm.map(|v| v * f);
        if let Some(c) = t.cyclic.as_mut() {
            c.amplitude_urad *= f;
        }
        t
    }
}

/// The targets of a pose set on `spec`'s machine (the grid column by column, as first written:
/// the measurement order is shuffled from it).
pub fn targets(poses: Poses, rng: &mut ChaCha8Rng, spec: &MachineSpec) -> Vec<[f64; 2]> {
    let ws = &spec.workspace;
    match poses {
        Poses::Grid5mm => {
            let g = &spec.grid;
            (0..g.nx).flat_map(|i| (0..g.ny).map(move |j| g.node_mm(i, j))).collect()
        }
        Poses::Table1 => crate::calib::protocol::table1_targets(ws).to_vec(),
        Poses::Random(n) => (0..n)
            .map(|_| [rng.random_range(ws.x_mm[0]..ws.x_mm[1]), rng.random_range(ws.y_mm[0]..ws.y_mm[1])])
            .collect(),
    }
}

/// Generates measurements of the truth machine, commanded by the nominal IK at the targets.
pub fn generate(truth: &Truth, poses: Poses, seed: u64) -> Vec<Measurement> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let spec = MachineSpec::paper();
    let nominal = spec.nominal;
    let mut cmds: Vec<([f64; 2], [f64; 2], [f64; 2])> = Vec::new(); // (theta, target, dir)
    for t in targets(poses, &mut rng, &spec) {
        if let Ok(th) = nominal.inverse(t, spec.min_transmission) {
            cmds.push((th, t, [sign(&mut rng), sign(&mut rng)]));
        }
    }
    // Measurement order is random (so time is not tied to position).
    for i in (1..cmds.len()).rev() {
        let j = rng.random_range(0..=i);
        cmds.swap(i, j);
    }
    let mut m = nominal;
    m.a_mm += truth.link_delta_um[0] * 1e-3;
    m.b_mm += truth.link_delta_um[1] * 1e-3;
    m.c_mm += truth.link_delta_um[2] * 1e-3;
    m.d_mm += truth.link_delta_um[3] * 1e-3;
    m.base_b0_mm = [truth.base_offset_um[0] * 1e-3, truth.base_offset_um[1] * 1e-3];
    // Ratio error about the circular mean angle of the poses (as the library defines it).
    let mean_th = [0, 1].map(|j| {
        let (s, c) = cmds.iter().fold((0.0, 0.0), |(s, c), cmd| (s + cmd.0[j].sin(), c + cmd.0[j].cos()));
        s.atan2(c)
    });
    let link_angle = |th: [f64; 2], dir: [f64; 2]| -> [f64; 2] {
        let mut g = [0.0; 2];
        for j in 0..2 {
            g[j] = th[j] + truth.encoder_offset_urad[j] * 1e-6 - dir[j] * truth.backlash_urad[j] * 0.5e-6
                + truth.gear_ppm[j] * 1e-6 * (th[j] - mean_th[j]);
            if let Some(c) = truth.cyclic {
                if c.motor == j {
                    g[j] += c.amplitude_urad * 1e-6 * (c.cycles * th[j] + c.phase_rad).sin();
                }
            }
        }
        g
    };
    // Distal angle ψ of the rigid truth machine at every pose (for the spring model).
    let psi: Vec<Option<f64>> = cmds
        .iter()
        .map(|(th, _, dir)| {
            let p = m.forward_pose(link_angle(*th, *dir), 0.0).ok()?;
            let q1 = [p.tool_mm[0] - p.elbow_a_mm[0], p.tool_mm[1] - p.elbow_a_mm[1]];
            let q2 = [p.tool_mm[0] - p.elbow_b_mm[0], p.tool_mm[1] - p.elbow_b_mm[1]];
            Some((q1[0] * q2[0] + q1[1] * q2[1]).atan2(q1[0] * q2[1] - q1[1] * q2[0]))
        })
        .collect();
    let ok: Vec<f64> = psi.iter().flatten().copied().collect();
    let nk = ok.len().max(1) as f64;
    let psi_mean = ok.iter().sum::<f64>() / nk;
    let quad_mean = ok.iter().map(|p| (p - psi_mean).powi(2)).sum::<f64>() / nk;
    let cube_mean = ok.iter().map(|p| (p - psi_mean).powi(3)).sum::<f64>() / nk;
    let noise = Normal::new(0.0, truth.noise_um.max(0.0) * 1e-3).ok();
    let mut out = Vec::new();
    for (k, ((th, target, dir), psi)) in cmds.iter().zip(&psi).enumerate() {
        let Some(psi) = psi else { continue };
        let dpsi = psi - psi_mean;
        // Preload force (arbitrary units): linear in ψ plus a quadratic term, zero mean.
        let force = dpsi
            + truth.stretch_quadratic_per_rad * (dpsi * dpsi - quad_mean)
            + truth.stretch_cubic_per_rad2 * (dpsi.powi(3) - cube_mean);
        let mut mk = m;
        mk.b_mm += truth.stretch_um_per_rad[0] * 1e-3 * force;
        mk.c_mm += truth.stretch_um_per_rad[1] * 1e-3 * force;
        let Ok(c) = mk.forward(link_angle(*th, *dir), 0.0) else { continue };
        let s = 1.0 + truth.scale_ppm * 1e-6;
        let c = [c[0] * s, c[1] * s];
        let (sn, cs) = (truth.frame[2] * 1e-6).sin_cos();
        let o = truth.frame_origin_mm;
        let d = [c[0] - o[0], c[1] - o[1]];
        let mut meas = [
            o[0] + cs * d[0] - sn * d[1] + truth.frame[0] * 1e-3,
            o[1] + sn * d[0] + cs * d[1] + truth.frame[1] * 1e-3,
        ];
        let t_s = 2.0 * k as f64;
        meas[0] += truth.drift_um_per_s[0] * 1e-3 * t_s;
        meas[1] += truth.drift_um_per_s[1] * 1e-3 * t_s;
        if let Some(nd) = noise {
            meas[0] += nd.sample(&mut rng);
            meas[1] += nd.sample(&mut rng);
        }
        out.push(Measurement {
            theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
            measured_mm: meas,
            target_mm: Some(*target),
            dir: Some([dir[0] as i8, dir[1] as i8]),
            run: None,
            t_s: Some(t_s),
            line: 0,
        });
    }
    out
}
