//! The checks of a fault scenario from its fault on, on the simulated plant's true state (not
//! the encoders, which may be the thing that lies) and on the simulated hardware (the
//! drive-enable line, the torque the PWM duty commands).
//!
//! Per stop category:
//! * **0** (torque off at once): from the fault's own sample, drive enable low and zero
//!   torque; each joint travels no further than the drives' dynamic braking lets it coast from
//!   its speed at the fault (`J·|ω|/(c + b)`: dynamic braking `c` and viscous friction `b`;
//!   Coulomb friction only shortens it; a joint that went further was pushed, or its drive does
//!   not brake); the tool never leaves the calibrated rectangle; the run ends with both joints
//!   at rest. Joints coupled through the linkage's inertia ([`CoastModel::coupled_inertia_kg_m2`]):
//!   the kinetic energy `½ωᵀMω` is what the braking and friction take away (the
//!   velocity-product torques do no work), `dE/dt ≤ -(c + b)·|ω|²`, so with `λ_min ≤ M ≤ λ_max`
//!   each joint's travel is at most `∫|ω| ≤ |ω₀|·λ_max·√(λ_max/λ_min)/(c + b)`, `|ω₀|` the
//!   norm of both joints' speeds. Dynamic braking is a hardware requirement of the drives
//!   (docs/reference/faults.md, "Category 0 needs dynamic braking"): once the torque is off the
//!   firmware can do nothing more, and free-wheeling drives coast out of the workspace from the
//!   tour's top speed.
//! * **1** (controlled stop, then torque off): drive enable on until the loop reports
//!   standstill, which must come within the stop's duration plus the settle timeout; then
//!   enable low and zero torque for good. The tool travels no further than the planned stop
//!   plus [`TRACKING_ALLOWANCE_MM`] and never leaves the calibrated rectangle.
//! * **2** (controlled stop, then hold): drive enable on throughout; the same distance and
//!   workspace bounds; from [`HOLD_AFTER_S`] past the stop's end the tool holds the stop's end
//!   point within [`MAX_HOLD_ERROR_MM`], and the loop reports `Holding`.
use crate::fault::StopCategory;
use crate::servo_loop::Mode;
use crate::stop::StopProfile;

pub use super::observation::PlantState;
use super::observation::{require, safe_state, Observation};

/// How far the tool may travel beyond the planned stop (mm): the servo's following error
/// during a 5 g stop (about 20 µm) with room to spare.
pub const TRACKING_ALLOWANCE_MM: f32 = 0.05;
/// Holding is checked from this long after the stop's planned end (s).
pub const HOLD_AFTER_S: f32 = 0.05;
/// Largest distance of a holding tool from the stop's end point (mm): 20 µm. After a 5 g stop
/// the integrator takes about 100 ms to give back what it took on, the tool wandering by about
/// 10 µm meanwhile (host test `servo_loop::tests::a_jump_at_top_speed_brakes_then_holds`).
pub const MAX_HOLD_ERROR_MM: f32 = 0.02;
/// A joint slower than this is at rest (rad/s).
pub const REST_RAD_S: f32 = 1.0e-3;

/// Enough of the plant to bound a coast with the drives off: inertia, viscous friction and the
/// drives' dynamic braking per joint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoastModel {
    /// Joint inertias (kg·m²).
    pub inertia_kg_m2: [f32; 2],
    /// Viscous friction (N·m·s/rad).
    pub viscous_nm_s_per_rad: f32,
    /// The drives' dynamic braking with the enable line low (N·m·s/rad at the joint).
    pub dynamic_brake_nm_s_per_rad: f32,
    /// Joints coupled through a linkage: `λ_max·√(λ_max/λ_min)` of the inertia matrix over the
    /// workspace (kg·m²; module doc); 0 for independent joints (the per-joint bound).
    pub coupled_inertia_kg_m2: f32,
}

impl CoastModel {
    /// The furthest joint `axis` can coast from `speed_rad_s` with the drives off (rad):
    /// `J·|ω|/(c + b)`, the speed decaying with the time constant `J/(c + b)`.
    pub fn bound_rad(&self, axis: usize, speed_rad_s: f32) -> f32 {
        self.inertia_kg_m2[axis] * speed_rad_s.abs()
            / (self.dynamic_brake_nm_s_per_rad + self.viscous_nm_s_per_rad)
    }

    /// Both joints' coast bounds from their speeds: [`CoastModel::bound_rad`] per joint, or with
    /// coupled joints `J_c·|ω|/(c + b)` for each (module doc).
    pub fn bounds_rad(&self, speed_rad_s: [f32; 2]) -> [f32; 2] {
        if self.coupled_inertia_kg_m2 > 0.0 {
            let speed = libm::hypotf(speed_rad_s[0], speed_rad_s[1]);
            let b = self.coupled_inertia_kg_m2 * speed
                / (self.dynamic_brake_nm_s_per_rad + self.viscous_nm_s_per_rad);
            [b; 2]
        } else {
            [0, 1].map(|k| self.bound_rad(k, speed_rad_s[k]))
        }
    }
}

/// What a stop did, for the log.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StopReport {
    /// The tool's speed at the fault (mm/s, from the plant's joint speeds through the model's
    /// Jacobian by finite difference over one sample).
    pub speed_mm_s: f32,
    /// The planned stop's distance (mm; category 1 and 2).
    pub planned_mm: f32,
    /// Furthest the tool got from where the stop began (mm): the stop's origin, the last
    /// accepted setpoint (categories 1 and 2); the tool at the fault (category 0). NaN once
    /// the forward kinematics refuse the joints (a coast past the reach).
    pub travelled_mm: f32,
    /// Each joint's travel since the fault (rad).
    pub joint_travel_rad: [f32; 2],
    /// Category 0: the coast bound per joint (rad), [`CoastModel::bound_rad`].
    pub coast_bound_rad: [f32; 2],
    /// Samples from the fault to torque off (0 for category 0; category 2 never).
    pub torque_off_after: u32,
    /// Largest distance from the stop's end point while holding (mm; category 2).
    pub hold_error_mm: f32,
    /// Whether the tool left the calibrated rectangle.
    pub left_workspace: bool,
}

/// The checks from the fault on.
#[derive(Clone, Copy, Debug)]
pub struct StopCheck {
    category: StopCategory,
    fault_sample: u32,
    from_tool_mm: Option<[f32; 2]>,
    from_joint_rad: [f32; 2],
    planned: Option<StopProfile>,
    sample_period_s: f32,
    settle_timeout_s: f32,
    report: StopReport,
}

impl StopCheck {
    /// Starts checking at the fault's sample. `planned` is the stop the checker expects from
    /// the setpoints it saw (category 1 and 2), `tool_mm` the tool's true position now (where
    /// a category-0 coast is measured from).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        category: StopCategory,
        fault_sample: u32,
        plant: &PlantState,
        tool_mm: Option<[f32; 2]>,
        speed_mm_s: f32,
        planned: Option<StopProfile>,
        coast: &CoastModel,
        sample_period_s: f32,
        settle_timeout_s: f32,
    ) -> Self {
        let report = StopReport {
            speed_mm_s,
            planned_mm: planned.map_or(0.0, |p| p.distance_mm()),
            coast_bound_rad: coast.bounds_rad(plant.joint_rad_s),
            ..StopReport::default()
        };
        StopCheck {
            category,
            fault_sample,
            from_tool_mm: planned.map(|p| p.origin_mm()).or(tool_mm),
            from_joint_rad: plant.joint_rad,
            planned,
            sample_period_s,
            settle_timeout_s,
            report,
        }
    }

    /// What the stop did so far.
    pub fn report(&self) -> StopReport {
        self.report
    }

    /// Samples after the fault at which the scenario concludes.
    pub fn conclude_after(&self) -> u32 {
        match self.category {
            // 0.5 s: a dynamically braked coast from 10 rad/s is over in about 50 ms, a free
            // coast against the QEMU plant's friction alone in about 0.3 s.
            StopCategory::Zero => 1_000,
            _ => {
                let end_s = self.planned.map_or(0.0, |p| p.duration_s())
                    + HOLD_AFTER_S
                    + self.settle_timeout_s;
                (end_s / self.sample_period_s) as u32 + 100
            }
        }
    }

    /// Checks sample `sample` (at or after the fault) with the tool's true position `tool_mm`
    /// (`None`: the forward kinematics refuse the joints) and whether it is in the calibrated
    /// rectangle. `Ok(true)`: the scenario has passed.
    pub fn observe(
        &mut self,
        o: &Observation<'_>,
        sample: u32,
        tool_mm: Option<[f32; 2]>,
        inside: bool,
    ) -> Result<bool, &'static str> {
        let since = sample.wrapping_sub(self.fault_sample);
        let done = since >= self.conclude_after();
        let r = &mut self.report;
        for k in 0..2 {
            r.joint_travel_rad[k] =
                r.joint_travel_rad[k].max((o.plant.joint_rad[k] - self.from_joint_rad[k]).abs());
        }
        r.travelled_mm = match (tool_mm, self.from_tool_mm) {
            (Some(p), Some(q)) if !r.travelled_mm.is_nan() => {
                r.travelled_mm.max(libm::hypotf(p[0] - q[0], p[1] - q[1]))
            }
            _ => f32::NAN,
        };
        r.left_workspace |= !inside;
        if !inside {
            return Err("the tool left the calibrated rectangle");
        }
        let planned_mm = r.planned_mm + TRACKING_ALLOWANCE_MM;
        match self.category {
            StopCategory::Zero => {
                safe_state(o)?;
                for k in 0..2 {
                    require(
                        r.joint_travel_rad[k] <= r.coast_bound_rad[k] + 1e-4,
                        "a joint coasted further than the dynamic-braking bound",
                    )?;
                }
                if done {
                    let still = o.plant.joint_rad_s.iter().all(|w| w.abs() < REST_RAD_S);
                    require(still, "the joints are not at rest at the end of the coast")?;
                }
            }
            StopCategory::One => {
                require(
                    !(r.travelled_mm > planned_mm),
                    "the stop went further than planned",
                )?;
                let off_by = self.planned.map_or(0.0, |p| p.duration_s()) + self.settle_timeout_s;
                if r.torque_off_after == 0 && o.drive_enable {
                    require(
                        (since as f32) * self.sample_period_s <= off_by + self.sample_period_s,
                        "torque not removed after the stop",
                    )?;
                } else {
                    if r.torque_off_after == 0 {
                        r.torque_off_after = since;
                        require(
                            matches!(o.status.mode, Mode::SafeState(_)),
                            "drive enable low but the loop is not in the safe state",
                        )?;
                    }
                    safe_state(o)?;
                }
                if done {
                    require(r.torque_off_after > 0, "torque never removed")?;
                }
            }
            StopCategory::Two => {
                require(o.drive_enable, "drive enable low during a category-2 stop")?;
                require(
                    !(r.travelled_mm > planned_mm),
                    "the stop went further than planned",
                )?;
                let hold_from = self.planned.map_or(0.0, |p| p.duration_s()) + HOLD_AFTER_S;
                if (since as f32) * self.sample_period_s >= hold_from {
                    let p = tool_mm.ok_or("the tool is nowhere while holding")?;
                    let end = self.planned.map_or(p, |s| s.end_mm());
                    r.hold_error_mm = r
                        .hold_error_mm
                        .max(libm::hypotf(p[0] - end[0], p[1] - end[1]));
                    require(
                        r.hold_error_mm <= MAX_HOLD_ERROR_MM,
                        "the tool does not hold the stop's end point",
                    )?;
                    require(
                        matches!(o.status.mode, Mode::Holding(_)),
                        "the loop is not holding after the stop",
                    )?;
                }
            }
        }
        Ok(done)
    }
}
