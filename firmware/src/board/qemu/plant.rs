//! The simulated machine: the five-bar linkage on two rotors, driven by the torques the PWM
//! registers command while the drive-enable line is on, read back through the encoder counters
//! (2^22 counts per revolution, quantised). With the enable line low the drives brake
//! dynamically (see [`MotorConstants`]).
//!
//! Its dynamics are the hidden robot's rigid-body dynamics with the two motors coupled through
//! the linkage (`kinematics_core::dynamics`: configuration-dependent inertia matrix,
//! centripetal and Coriolis torques) plus the rotors' inertia, with viscous and smoothed
//! Coulomb friction at each motor: `(M(θ) + J_r)·θ̈ + h(θ, θ̇) + friction(θ̇) = τ`. The plant's
//! parameters are deliberately not the ones in the calibration image the servo feeds forward
//! (`machine.rs`, written into the image by `firmware/build.rs`): every inertia and the tool
//! mass are 20 % off, alternating in sign, and the friction differs, so the feedback has a
//! real remainder to correct.
//!
//! Integration, once per servo sample (the torque written in sample k acts during period
//! k..k+1, as on hardware): `M` and `h` at the middle of the period (the pose predicted from the
//! current velocity), then `substeps` steps with the friction and the brake updated and the
//! position advanced with the mean velocity of each step (second order). Cost: one FK and three
//! inverse-dynamics evaluations per sample (about 1,200 instructions), far inside the 62,500
//! instructions of a 500 µs period at QEMU's `-icount shift=3`.
use controller::scenario::stop_check::{CoastModel, PlantState};
use kinematics_core::dynamics::{solve_spd, FiveBarDynamics};
use kinematics_core::jacobian::Mat2;
use kinematics_core::FiveBar;

use super::hardware;
use super::machine::{LINKAGE, ROTOR_INERTIA_KG_M2};
use super::COUNTS_PER_REV;

/// Parameters of the simulated machine.
#[derive(Clone, Copy, Debug)]
pub struct PlantParams {
    /// The rotors' inertia at the joints (kg·m²).
    pub inertia_kg_m2: [f32; 2],
    /// The linkage's bodies lumped into the hidden robot (friction below, not in here).
    pub linkage: FiveBarDynamics<f32>,
    /// Viscous friction (N·m·s/rad).
    pub viscous_nm_s_per_rad: f32,
    /// Coulomb friction (N·m), smoothed over [`PlantParams::coulomb_smoothing_rad_s`].
    pub coulomb_nm: f32,
    /// Speed (rad/s) over which the Coulomb friction turns over.
    pub coulomb_smoothing_rad_s: f32,
    /// Integration sub-steps per servo period.
    pub substeps: u32,
    /// The drives' dynamic braking with the enable line low (N·m·s/rad): a braking torque
    /// `-c·ω` on each joint. [`MOTOR`]'s, 0.225.
    pub dynamic_brake_nm_s_per_rad: f32,
}

/// A drive's motor, for its dynamic braking.
///
/// **Dynamic braking is a hardware requirement of the drives** (docs/reference/faults.md, "Category
/// 0 needs dynamic braking"): on disable, safe torque off or a break, the amplifier shorts the motor's
/// windings. The back-EMF `k_e·N·ω` then drives a current `k_e·N·ω/R` through the winding
/// resistance, whose torque `k_t·N·k_e·N·ω/R` at the joint brakes the joint, in proportion to
/// its speed, with no energy from the supply and with the controller dead:
/// `c = N²·k_t·k_e/R` (N·m·s/rad at the joint). The simple resistive model holds while the
/// winding's electrical time constant is short against the electrical period (`ω_e·L/R ≪ 1`:
/// 10 pole pairs, 3 mH, 3.6 Ω at 9 rad/s give 0.075, 0.6 % less torque); at higher speeds the
/// inductance lowers the braking torque.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorConstants {
    /// Torque constant (N·m/A).
    pub torque_constant_nm_per_a: f32,
    /// Back-EMF constant (V·s/rad; equal to the torque constant in SI units for an ideal motor).
    pub back_emf_v_s_per_rad: f32,
    /// Winding resistance the short closes the circuit through (Ω: terminal resistance plus the
    /// short's).
    pub winding_resistance_ohm: f32,
    /// Motor turns per joint turn (1: direct drive).
    pub gear_ratio: f32,
}

impl MotorConstants {
    /// The dynamic braking at the joint (N·m·s/rad): `N²·k_t·k_e/R`.
    pub const fn dynamic_brake_nm_s_per_rad(&self) -> f32 {
        self.gear_ratio
            * self.gear_ratio
            * self.torque_constant_nm_per_a
            * self.back_emf_v_s_per_rad
            / self.winding_resistance_ohm
    }
}

/// The simulated drives' motors: a small brushless direct-drive torque motor of the 10 N·m
/// peak class (the drives' full scale), representative values, not a particular part:
/// `k_t` = 0.9 N·m/A (11 A for 10 N·m), `k_e` = 0.9 V·s/rad, `R` = 3.6 Ω, direct drive
/// (`N` = 1, as the QEMU board's encoders are). Dynamic braking `c` = 0.81/3.6 =
/// **0.225 N·m·s/rad** (the motor constant `k_m = k_t/√R` = 0.47 N·m/√W squared). From the
/// built-in tour's top speed (1.38 m/s) a category-0 coast of the coupled joints is bounded by
/// 0.60 rad per joint (`stop_check`'s coupled bound); measured, joint 1 coasts 0.27 rad and
/// the tool 40 mm; free-wheeling drives coasted the tool 77-79 mm, out of the workspace.
pub const MOTOR: MotorConstants = MotorConstants {
    torque_constant_nm_per_a: 0.9,
    back_emf_v_s_per_rad: 0.9,
    winding_resistance_ohm: 3.6,
    gear_ratio: 1.0,
};

impl Default for PlantParams {
    fn default() -> Self {
        PlantParams {
            inertia_kg_m2: ROTOR_INERTIA_KG_M2,
            linkage: LINKAGE,
            viscous_nm_s_per_rad: 0.01,
            coulomb_nm: 0.03,
            coulomb_smoothing_rad_s: 1.0e-3,
            substeps: 10,
            dynamic_brake_nm_s_per_rad: MOTOR.dynamic_brake_nm_s_per_rad(),
        }
    }
}

/// Joint angles the simulated machine powers up at (rad): tool near (214, 3) mm.
pub const POWER_ON_ANGLES_RAD: [f32; 2] = [0.80, -0.75];

/// The tool rectangle the coast bound's inertia extremes are taken over (mm: x from, x to,
/// y from, y to): the calibrated rectangle (`build.rs`'s grid, 162..262 × −75..75) with a
/// margin.
pub const COAST_RECTANGLE_MM: [f32; 4] = [155.0, 270.0, -82.0, 82.0];
/// Lattice points per side the extremes are sampled on (the inertia matrix varies slowly:
/// 17² points find its extreme eigenvalues to well under 1 %, and the bound has room).
const COAST_LATTICE: usize = 17;

/// The simulated machine.
#[derive(Clone, Copy, Debug)]
pub struct Plant {
    /// Dynamics, friction, integration.
    pub params: PlantParams,
    /// The linkage's geometry (the paper's nominal five-bar, the one the image's model is).
    pub geometry: FiveBar<f32>,
    /// Joint angles (rad), as the encoders count them.
    pub angle_rad: [f32; 2],
    /// Joint velocities (rad/s).
    pub velocity_rad_s: [f32; 2],
    /// The drives' full scale (N·m at 0 % / 100 % duty).
    pub full_scale_nm: f32,
    /// The linkage left its assembly (a singular or unreachable pose): the plant stopped.
    pub jammed: bool,
    /// `λ_max·√(λ_max/λ_min)` of the whole inertia matrix over [`COAST_RECTANGLE_MM`] (kg·m²).
    coupled_inertia_kg_m2: f32,
    /// Joint angle of each axis's index mark (rad; `None`: the mark is missing).
    pub index_rad: [Option<f32>; 2],
}

/// Joint angle of the simulated encoders' index marks (rad): the firmware's default
/// `HomingSettings::index_rad`.
pub const INDEX_RAD: [f32; 2] = [1.40, -1.40];

/// The plant's count of joint angle `rad`.
fn counts_of(rad: f32) -> i32 {
    libm::roundf(rad * (COUNTS_PER_REV as f32 / (2.0 * core::f32::consts::PI))) as i32
}

impl Plant {
    /// The machine at power-on, at rest, its encoders published.
    pub fn power_on(full_scale_nm: f32) -> Self {
        let params = PlantParams::default();
        let geometry = FiveBar::paper_nominal();
        let plant = Plant {
            params,
            geometry,
            angle_rad: POWER_ON_ANGLES_RAD,
            velocity_rad_s: [0.0; 2],
            full_scale_nm,
            jammed: false,
            coupled_inertia_kg_m2: coupled_inertia_kg_m2(&params, &geometry),
            index_rad: [Some(INDEX_RAD[0]), Some(INDEX_RAD[1])],
        };
        plant.publish_encoders();
        plant
    }

    /// Incremental encoders: the machine powers up at `tool_mm` (unknown to the firmware) and
    /// the counters read 0 there; `index` says which axes have their index mark.
    pub fn power_on_incremental(&mut self, tool_mm: [f32; 2], index: [bool; 2]) {
        if let Ok(angles) = self.geometry.inverse(tool_mm, 0.0) {
            self.angle_rad = angles;
        }
        for (k, has_index) in index.into_iter().enumerate() {
            hardware::set_counter_zero(k, counts_of(self.angle_rad[k]));
            if !has_index {
                self.index_rad[k] = None;
            }
        }
        self.publish_encoders();
    }

    /// The true joint state (the harness checks it, not the encoders).
    pub fn state(&self) -> PlantState {
        PlantState {
            joint_rad: self.angle_rad,
            joint_rad_s: self.velocity_rad_s,
        }
    }

    /// What bounds a coast with the drives off: the coupled inertia, viscous friction and the
    /// drives' dynamic braking.
    pub fn coast_model(&self) -> CoastModel {
        CoastModel {
            inertia_kg_m2: self.params.inertia_kg_m2,
            viscous_nm_s_per_rad: self.params.viscous_nm_s_per_rad,
            dynamic_brake_nm_s_per_rad: self.params.dynamic_brake_nm_s_per_rad,
            coupled_inertia_kg_m2: self.coupled_inertia_kg_m2,
        }
    }

    /// The machine as it was when its controller reset (it does not stop with it).
    pub fn resume(&mut self, state: PlantState) {
        self.angle_rad = state.joint_rad;
        self.velocity_rad_s = state.joint_rad_s;
        self.publish_encoders();
    }

    fn publish_encoders(&self) {
        for k in 0..2 {
            hardware::set_encoder_counts(k, counts_of(self.angle_rad[k]));
        }
    }

    /// Advances the machine by `period_s` under the torques the PWM commands now, or, with the
    /// enable line low, under the drives' dynamic braking. A pose the linkage cannot take
    /// (driven through a singularity) jams it: it stops where it is.
    pub fn advance(&mut self, period_s: f32) {
        let (torque_nm, brake_nm_s_per_rad) = if hardware::drive_enable() {
            (hardware::commanded_torque_nm(self.full_scale_nm), 0.0)
        } else {
            ([0.0; 2], self.params.dynamic_brake_nm_s_per_rad)
        };
        let before = self.angle_rad;
        if !self.jammed
            && self
                .integrate(torque_nm, brake_nm_s_per_rad, period_s)
                .is_none()
        {
            self.jammed = true;
            self.velocity_rad_s = [0.0; 2];
        }
        for (k, (from, to)) in before.into_iter().zip(self.angle_rad).enumerate() {
            if let Some(i) = self.index_rad[k] {
                if from != to && (from - i) * (to - i) <= 0.0 {
                    hardware::index_pulse(k, counts_of(i));
                }
            }
        }
        self.publish_encoders();
    }

    fn integrate(
        &mut self,
        torque_nm: [f32; 2],
        brake_nm_s_per_rad: f32,
        period_s: f32,
    ) -> Option<()> {
        let p = self.params;
        let (mut angle, mut velocity) = (self.angle_rad, self.velocity_rad_s);
        let half = 0.5 * period_s;
        let mid = [angle[0] + velocity[0] * half, angle[1] + velocity[1] * half];
        let pose = self.geometry.forward_pose(mid, 0.0).ok()?;
        let (m, bias) = mass_matrix_and_bias(&p, &pose, velocity)?;
        let h = period_s / p.substeps as f32;
        for _ in 0..p.substeps {
            let mut r = [0.0f32; 2];
            for k in 0..2 {
                let w = velocity[k];
                let friction = p.viscous_nm_s_per_rad * w
                    + p.coulomb_nm * w / (w.abs() + p.coulomb_smoothing_rad_s);
                r[k] = torque_nm[k] - bias[k] - friction - brake_nm_s_per_rad * w;
            }
            let acc = solve_spd(&m, r).ok()?;
            for k in 0..2 {
                let before = velocity[k];
                velocity[k] += acc[k] * h;
                angle[k] += 0.5 * (before + velocity[k]) * h;
            }
        }
        if !(angle.iter().chain(velocity.iter()).all(|v| v.is_finite())) {
            return None;
        }
        self.angle_rad = angle;
        self.velocity_rad_s = velocity;
        Some(())
    }
}

/// The whole machine's inertia matrix (linkage plus rotors) and velocity-product torques.
fn mass_matrix_and_bias(
    p: &PlantParams,
    pose: &kinematics_core::Pose<f32>,
    velocity_rad_s: [f32; 2],
) -> Option<(Mat2<f32>, [f32; 2])> {
    let (mut m, bias) = p.linkage.mass_matrix_and_bias(pose, velocity_rad_s).ok()?;
    m[0][0] += p.inertia_kg_m2[0];
    m[1][1] += p.inertia_kg_m2[1];
    Some((m, bias))
}

/// `λ_max·√(λ_max/λ_min)` of the whole inertia matrix over [`COAST_RECTANGLE_MM`]'s lattice
/// (the coast bound's inertia, `stop_check`'s module doc). Poses the model cannot reach are
/// skipped; should none be reachable (a broken geometry), the rotors' sum alone is no bound,
/// so it returns infinity and every coast check fails loudly.
fn coupled_inertia_kg_m2(p: &PlantParams, geometry: &FiveBar<f32>) -> f32 {
    let [x0, x1, y0, y1] = COAST_RECTANGLE_MM;
    let (mut low, mut high) = (f32::INFINITY, 0.0f32);
    let n = COAST_LATTICE - 1;
    for i in 0..=n {
        for j in 0..=n {
            let tool = [
                x0 + (x1 - x0) * i as f32 / n as f32,
                y0 + (y1 - y0) * j as f32 / n as f32,
            ];
            let Ok(pose) = geometry.inverse_pose(tool, 0.0) else {
                continue;
            };
            let Some((m, _)) = mass_matrix_and_bias(p, &pose, [0.0; 2]) else {
                continue;
            };
            let mean = 0.5 * (m[0][0] + m[1][1]);
            let spread = libm::hypotf(0.5 * (m[0][0] - m[1][1]), m[0][1]);
            low = low.min(mean - spread);
            high = high.max(mean + spread);
        }
    }
    if low > 0.0 && high.is_finite() {
        high * libm::sqrtf(high / low)
    } else {
        f32::INFINITY
    }
}
