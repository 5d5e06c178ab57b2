//! Encoder plausibility: readings the mechanism cannot produce, and encoders that do not move
//! under torque. Every finding is a category-0 fault (torque off at once): the servo would
//! otherwise act on a position that is not the machine's.
//!
//! Run on every sample while the drives are on, before the servo step, with the torque that
//! acted since the previous reading (the one the previous sample wrote).
//!
//! * **Speed**: `|Δθ| > max_speed·dt` (one sample's difference).
//! * **Acceleration**: `|Δ²θ| > max_accel·dt²` (the second difference). This is what catches a
//!   **glitch** (a single-sample jump `δ` shows as `+δ`, then `-2δ`) and an encoder that
//!   **freezes while moving** (the reading stops dead: `ω/dt`). The bound is what the drives
//!   can do, `max_accel` (default 6000 rad/s², 1.5x the torque limit over the feed-forward
//!   inertia: 8 N·m / 2·10⁻³ kg·m² = 4000 rad/s², so an axis up to 1.5x lighter than assumed
//!   passes). A glitch `δ` from steady motion is caught in its own sample when
//!   `|δ| > max_accel·dt²` = 1.5·10⁻³ rad (1,000 counts at 2²² counts/rev, 0.23 mm at a 150 mm
//!   link), and in the next, when the reading comes back, when `|δ|` is more than half that
//!   (0.75·10⁻³ rad); quantisation noise is 2 counts. Below, the servo takes the glitch as a
//!   one-sample kick of at most `kp·δ + kd·δ/dt` = 2.5 N·m with the default gains. A
//!   freeze is caught at once above `max_accel·dt` = 3 rad/s; below, by the stuck check.
//! * **Stuck** (an encoder that stopped counting, or a blocked axis), at rest too: while the
//!   torque that acted exceeds `hold_torque` (the most an axis may hold without moving: static
//!   friction plus any static load) with one sign, the axis must accelerate at least at
//!   `(|τ| - hold_torque)/max_inertia`. The check integrates that expected motion from the
//!   last sample the reading changed by a count; when it exceeds `stuck_motion` with the
//!   reading unchanged, the encoder (or the axis) is stuck. A changing reading, a torque sign
//!   change or a torque within `hold_torque` restart it, so friction, a static load and a
//!   reversal never trip it. **Coupled axes**: on a linkage an axis stands still while the
//!   other moves only if it holds what the other's motion puts on it: the coupling inertia
//!   times the other axis's acceleration and the velocity products times its speed squared
//!   (`M₁₂·α₂ + c·ω₂²`). The torque counted is what is left above `hold_torque` plus
//!   `max_coupling_inertia·|α_other| + max_velocity_product·ω_other²`, both from the other
//!   axis's readings (its second and first differences). Without it, the paper six-bar's axis 1
//!   standing still while axis 2 starts a move at 130 rad/s² (holding 0.26 to 0.31 N·m) was
//!   "stuck" after 6 samples (host test `an_axis_holding_still_while_the_other_accelerates_...`,
//!   recorded in co-simulation). A frozen encoder is then found once its servo's torque passes
//!   the holding torque by `hold_torque` plus the allowance: under a 400 rad/s² bang-bang of the
//!   other axis (1.44 N·m of allowance for its acceleration, up to 0.56 N·m more at its
//!   10 rad/s) and a servo torque ramping 0.05 N·m per
//!   sample, after 19 samples (host test `coupled_axes_hold_without_a_stuck_finding_...`). **Detection time** under a constant torque `τ`: the first sample
//!   `n` with `a·(n·dt)²/2 > stuck_motion`, `a = (|τ| - hold_torque)/max_inertia`; with the
//!   defaults (0.2 N·m, 3·10⁻³ kg·m², 10⁻⁴ rad): 1 sample (0.5 ms) at the 8 N·m limit, 2 (1 ms)
//!   at 1 N·m, 3 (1.5 ms) at 0.5 N·m. The torque itself comes from the servo: an encoder
//!   frozen at rest is noticed once the reference moves away from it and the torque passes
//!   `hold_torque`, i.e. when the machine is asked to move (a frozen encoder on a machine
//!   holding still is indistinguishable from a still machine, and harmless). Measured on the
//!   QEMU plant's parameters, joint 1 frozen before a 2 g move: found 10 samples (5 ms) after
//!   the first move of the tour starts, the tool 0.058 mm off, 0.68 mm after coasting (host
//!   test `servo_loop::tests::an_encoder_frozen_at_rest_is_stuck_...`, free-wheeling drives,
//!   `-- --nocapture`); a 0.32 mm coast with the drives' dynamic braking before the long
//!   diagonal (`cargo qemu-test`, `encoder-frozen-at-rest`, its `stop:` line). Which joint
//!   and which move decide how fast the servo's torque builds up.
//!
//! **Resolution.** Every bound above is widened by the encoder's quantisation, from the
//! per-axis scale (`Settings::encoders`, [`EncoderScale::rad_per_count`](crate::encoder::EncoderScale::rad_per_count)):
//! one count on the speed bound, two on the acceleration bound (the second difference of
//! readings rounded to counts is off by up to two counts), and the stuck check needs more than
//! four counts of expected motion: the expected motion is counted from rest, but an axis that
//! was moving against the torque when the reading last changed turns around inside one count
//! for up to `sqrt(8·count/a)`, during which the motion from rest reaches `½·a·t²` = 4 counts.
//! At the default 2²² counts/rev (1.5 µrad per count) this changes none of the figures above;
//! it is what keeps a coarse encoder (4096 counts/rev direct drive: 1.5 mrad per count, as much
//! as one sample's acceleration bound) from reading its own quantisation as a glitch or a stuck
//! axis. The glitch and stuck thresholds grow accordingly: a geared axis (10,000 counts/rev
//! through 50:1 is 12.6 µrad per count) keeps them within 2 % of the figures above.
//!
//! On a real axis: a breakaway friction or a static load (a spring, the six-bar's preload)
//! above `hold_torque` trips it; commissioning sets it from the largest holding torque
//! measured. An axis heavier than `max_inertia` moves less than expected and can trip it too.
//! The QEMU plant's friction is 0.03 N·m, its inertias 2.2 and 1.8·10⁻³ kg·m².

/// The encoder check's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderLimits {
    /// The fastest a joint can turn (rad/s). Default 100 rad/s: the built-in tour needs about
    /// 10, the servo's 3 m/s setpoint limit about 30 away from singularities.
    pub max_speed_rad_s: f32,
    /// The largest joint acceleration the drives can produce (rad/s²). Default 6000.
    pub max_accel_rad_s2: f32,
    /// The largest torque an axis may hold without moving (N·m): static friction plus static
    /// load. Default 0.2 N·m (the QEMU plant's friction is 0.03 N·m; a real axis sets it at
    /// commissioning from the largest holding torque measured).
    pub hold_torque_nm: f32,
    /// The largest effective joint inertia (kg·m²). Default 3·10⁻³ (1.5x the feed-forward's).
    pub max_inertia_kg_m2: f32,
    /// The largest coupling inertia between the two axes (kg·m², the inertia matrix's
    /// off-diagonal term `|M₁₂|` over the workspace; ≥ 0): an axis that stands still while the
    /// other accelerates at `α` holds `M₁₂·α` without moving. Default 3.6·10⁻³ (1.5x the paper
    /// machine's 2.42·10⁻³).
    pub max_coupling_inertia_kg_m2: f32,
    /// The largest velocity-product coefficient (kg·m², N·m per (rad/s)²; ≥ 0): an axis that
    /// stands still while the other turns at `ω` holds up to this times `ω²` (centrifugal and
    /// Coriolis torques) without moving. Default 5.6·10⁻³ (1.5x the paper machine's
    /// 3.72·10⁻³).
    pub max_velocity_product_kg_m2: f32,
    /// Expected motion (rad) with an unchanged reading that makes the encoder stuck. Default
    /// 10⁻⁴ rad (67 counts at 2²² counts/rev).
    pub stuck_motion_rad: f32,
}

impl Default for EncoderLimits {
    fn default() -> Self {
        EncoderLimits {
            max_speed_rad_s: 100.0,
            max_accel_rad_s2: 6_000.0,
            hold_torque_nm: 0.2,
            max_inertia_kg_m2: 3.0e-3,
            max_coupling_inertia_kg_m2: 3.6e-3,
            max_velocity_product_kg_m2: 5.6e-3,
            stuck_motion_rad: 1.0e-4,
        }
    }
}

impl EncoderLimits {
    /// Every field finite and positive (the coupling terms may be zero: axes that do not
    /// couple); returns the name of the first that is not.
    pub fn validate(&self) -> Result<(), &'static str> {
        for (v, name) in [
            (
                self.max_coupling_inertia_kg_m2,
                "encoder_limits.max_coupling_inertia_kg_m2",
            ),
            (
                self.max_velocity_product_kg_m2,
                "encoder_limits.max_velocity_product_kg_m2",
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(name);
            }
        }
        for (v, name) in [
            (self.max_speed_rad_s, "encoder_limits.max_speed_rad_s"),
            (self.max_accel_rad_s2, "encoder_limits.max_accel_rad_s2"),
            (self.hold_torque_nm, "encoder_limits.hold_torque_nm"),
            (self.max_inertia_kg_m2, "encoder_limits.max_inertia_kg_m2"),
            (self.stuck_motion_rad, "encoder_limits.stuck_motion_rad"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(name);
            }
        }
        Ok(())
    }
}

/// What the check found wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncoderFaultKind {
    /// The reading is NaN or infinite.
    NonFinite,
    /// One sample's difference is faster than the mechanism can turn.
    Speed,
    /// The second difference is more than the drives can accelerate: a glitch, or a reading
    /// that stopped dead.
    Acceleration,
    /// No count changed while the torque should have moved the axis.
    Stuck,
}

/// An implausible encoder: which axis, and what.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderFault {
    /// 0 or 1.
    pub axis: u8,
    /// What is wrong.
    pub kind: EncoderFaultKind,
}

impl core::fmt::Display for EncoderFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let what = match self.kind {
            EncoderFaultKind::NonFinite => "non-finite reading",
            EncoderFaultKind::Speed => "speed beyond the mechanism's",
            EncoderFaultKind::Acceleration => {
                "acceleration beyond the drives' (a glitch, or a reading that stopped)"
            }
            EncoderFaultKind::Stuck => "no motion under torque (stuck encoder or blocked axis)",
        };
        write!(f, "axis {}: {}", self.axis + 1, what)
    }
}

/// Motion the torque should have produced since the reading last changed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Expected {
    speed_rad_s: f32,
    motion_rad: f32,
    /// Sign of the torque it was accumulated under (0: nothing accumulated).
    sign: f32,
}

/// The check's state: the last readings and the expected motion per axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncoderCheck {
    /// One count of each axis's encoder (rad, positive): the quantisation the bounds allow.
    count_rad: [f32; 2],
    last_rad: [f32; 2],
    last_step_rad: [f32; 2],
    expected: [Expected; 2],
}

impl EncoderCheck {
    /// Starts at `encoder_rad`, at rest; `count_rad` is one count of each axis's encoder (rad;
    /// the sign is ignored, and a non-finite value counts as 0: the unwidened bounds).
    pub fn new(encoder_rad: [f32; 2], count_rad: [f32; 2]) -> Self {
        let count_rad = count_rad.map(|c| if c.is_finite() { c.abs() } else { 0.0 });
        EncoderCheck {
            count_rad,
            last_rad: encoder_rad,
            last_step_rad: [0.0; 2],
            expected: [Expected::default(); 2],
        }
    }

    /// One count of each axis (rad), as given to `new`.
    pub fn count_rad(&self) -> [f32; 2] {
        self.count_rad
    }

    /// The readings' zero moved (homing set the reference): the readings from now on are the
    /// old ones plus `offset_rad`. Speeds and the stuck check carry on.
    pub fn shift(&mut self, offset_rad: [f32; 2]) {
        self.last_rad = [
            self.last_rad[0] + offset_rad[0],
            self.last_rad[1] + offset_rad[1],
        ];
    }

    /// The last sample's joint speeds (rad/s): the difference of the last two readings.
    pub fn speed_rad_s(&self, dt_s: f32) -> [f32; 2] {
        [self.last_step_rad[0] / dt_s, self.last_step_rad[1] / dt_s]
    }

    /// Checks a new reading; `torque_nm` acted since the previous one. On `Err` the state is
    /// left as it was (the fault is latched and the check is not run again).
    pub fn check(
        &mut self,
        encoder_rad: [f32; 2],
        torque_nm: [f32; 2],
        limits: &EncoderLimits,
        dt_s: f32,
    ) -> Result<(), EncoderFault> {
        let mut next = *self;
        let steps = [
            encoder_rad[0] - self.last_rad[0],
            encoder_rad[1] - self.last_rad[1],
        ];
        for k in 0..2 {
            let fault = |kind| EncoderFault {
                axis: k as u8,
                kind,
            };
            if !encoder_rad[k].is_finite() {
                return Err(fault(EncoderFaultKind::NonFinite));
            }
            let count = self.count_rad[k];
            let step = steps[k];
            if !(step.abs() <= limits.max_speed_rad_s * dt_s + count) {
                return Err(fault(EncoderFaultKind::Speed));
            }
            if !((step - self.last_step_rad[k]).abs()
                <= limits.max_accel_rad_s2 * dt_s * dt_s + 2.0 * count)
            {
                return Err(fault(EncoderFaultKind::Acceleration));
            }
            let e = &mut next.expected[k];
            // What the other axis's motion takes without moving this one: its acceleration
            // through the coupling inertia, its speed through the velocity products (both
            // from its readings; the other axis's own checks vouch for them).
            let j = 1 - k;
            let other_speed_rad_s = steps[j] / dt_s;
            let other_accel_rad_s2 = (steps[j] - self.last_step_rad[j]) / (dt_s * dt_s);
            let coupled_nm = limits.max_coupling_inertia_kg_m2 * other_accel_rad_s2.abs()
                + limits.max_velocity_product_kg_m2 * other_speed_rad_s * other_speed_rad_s;
            let excess = torque_nm[k].abs() - limits.hold_torque_nm - coupled_nm;
            let sign = if torque_nm[k] > 0.0 { 1.0 } else { -1.0 };
            if step != 0.0 || !(excess > 0.0) || (e.sign != 0.0 && e.sign != sign) {
                *e = Expected::default();
            } else {
                e.sign = sign;
                // Exact for a constant acceleration over the sample (trapezoid on the speed).
                let accel = excess / limits.max_inertia_kg_m2;
                e.motion_rad += (e.speed_rad_s + 0.5 * accel * dt_s) * dt_s;
                e.speed_rad_s += accel * dt_s;
                if e.motion_rad > limits.stuck_motion_rad.max(4.0 * count) {
                    return Err(fault(EncoderFaultKind::Stuck));
                }
            }
            next.last_rad[k] = encoder_rad[k];
            next.last_step_rad[k] = step;
        }
        *self = next;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT_S: f32 = crate::SAMPLE_PERIOD_S;
    /// One count at 2²² counts/rev (rad).
    const COUNT_RAD: f32 = 2.0 * core::f32::consts::PI / (1u32 << 22) as f32;

    fn quantise(rad: f32) -> f32 {
        quantise_to(rad, COUNT_RAD)
    }

    fn quantise_to(rad: f32, count_rad: f32) -> f32 {
        libm::roundf(rad / count_rad) * count_rad
    }

    /// An axis: inertia, Coulomb friction, the encoder quantised; `torque(k, θ, ω)` per sample.
    /// Returns the first fault and the sample it came in.
    fn run(
        samples: usize,
        inertia_kg_m2: f32,
        friction_nm: f32,
        torque: impl FnMut(usize, f32, f32) -> f32,
        reading: impl FnMut(usize, f32) -> f32,
    ) -> Option<(usize, EncoderFault)> {
        run_with(
            COUNT_RAD,
            samples,
            inertia_kg_m2,
            friction_nm,
            torque,
            reading,
        )
    }

    /// [`run`] with an encoder of `count_rad` per count (the reading passed to `reading` is
    /// quantised to it, and the check knows it).
    fn run_with(
        count_rad: f32,
        samples: usize,
        inertia_kg_m2: f32,
        friction_nm: f32,
        mut torque: impl FnMut(usize, f32, f32) -> f32,
        mut reading: impl FnMut(usize, f32) -> f32,
    ) -> Option<(usize, EncoderFault)> {
        let limits = EncoderLimits::default();
        let (mut angle, mut speed) = (0.9f32, 0.0f32);
        let quantise = |rad| quantise_to(rad, count_rad);
        let mut check = EncoderCheck::new([quantise(angle), -0.7], [count_rad, COUNT_RAD]);
        let mut tau = 0.0f32;
        for k in 0..samples {
            // The torque of the previous sample acts for one period (10 sub-steps).
            for _ in 0..10 {
                let h = DT_S / 10.0;
                let f = if speed.abs() > 1e-4 {
                    friction_nm * speed.signum()
                } else {
                    tau.clamp(-friction_nm, friction_nm)
                };
                speed += (tau - f) / inertia_kg_m2 * h;
                angle += speed * h;
            }
            let read = reading(k, quantise(angle));
            if let Err(f) = check.check([read, -0.7], [tau, 0.0], &limits, DT_S) {
                return Some((k, f));
            }
            tau = torque(k, angle, speed);
        }
        None
    }

    /// The torque (N·m) of a fast move with reversals, the profile two tests drive an axis
    /// with at sample `k` and speed `w` (rad/s): ±2 N·m bang-bang reversing every 40 ms for
    /// 1.5 s, then braked to rest and 0.15 N·m held.
    fn reversing_torque_nm(k: usize, _: f32, w: f32) -> f32 {
        if k < 3000 {
            if (k / 80) % 2 == 0 {
                2.0
            } else {
                -2.0
            }
        } else if w.abs() > 0.1 {
            -2.0 * w.signum()
        } else {
            0.15
        }
    }

    #[test]
    fn a_fast_move_with_friction_and_reversals_is_plausible() {
        // ±2 N·m bang-bang reversing every 40 ms against 0.18 N·m of friction (up to about
        // 35 rad/s, 800 rad/s²); then 0.15 N·m (below hold_torque, and below the friction) held
        // at rest, where the reading does not change for 0.5 s.
        let fault = run(4000, 2.2e-3, 0.18, reversing_torque_nm, |_, r| r);
        assert_eq!(fault, None);
    }

    /// An axis under a steady 0.2 N·m whose reading jumps by `delta_rad` in sample 400 only.
    fn glitch_at_400(delta_rad: f32) -> Option<(usize, EncoderFault)> {
        run(
            600,
            2.2e-3,
            0.03,
            |_, _, _| 0.2,
            |k, r| if k == 400 { r + delta_rad } else { r },
        )
    }

    #[test]
    fn glitches_are_caught_in_their_sample_or_when_the_reading_returns() {
        for delta in [1.6e-3f32, 5e-3, 0.02, -0.05] {
            let fault = glitch_at_400(delta);
            let (at, f) = fault.unwrap_or_else(|| panic!("glitch {delta} not caught"));
            assert_eq!((at, f.axis), (400, 0), "{delta}");
            assert!(
                matches!(
                    f.kind,
                    EncoderFaultKind::Acceleration | EncoderFaultKind::Speed
                ),
                "{f:?}"
            );
        }
        // Between half the bound and the bound: caught when the reading comes back (-2δ).
        for delta in [0.8e-3f32, -1.2e-3] {
            let fault = glitch_at_400(delta);
            assert_eq!(
                fault,
                Some((
                    401,
                    EncoderFault {
                        axis: 0,
                        kind: EncoderFaultKind::Acceleration
                    }
                )),
                "{delta}"
            );
        }
        // Below half the bound it is noise to this check (the servo takes it as a small kick).
        assert_eq!(glitch_at_400(0.7e-3), None);
    }

    #[test]
    fn a_reading_that_stops_dead_at_speed_is_caught_at_once() {
        // 1 N·m accelerates the axis to ~20 rad/s in 50 ms; from sample 100 on the reading is
        // the one of sample 99.
        let mut last = 0.0;
        let fault = run(
            200,
            2.2e-3,
            0.03,
            |_, _, _| 1.0,
            |k, r| {
                if k < 100 {
                    last = r;
                }
                last
            },
        );
        assert_eq!(
            fault,
            Some((
                100,
                EncoderFault {
                    axis: 0,
                    kind: EncoderFaultKind::Acceleration
                }
            ))
        );
    }

    #[test]
    fn a_jump_faster_than_the_mechanism_is_a_speed_fault() {
        let fault = run(
            300,
            2.2e-3,
            0.03,
            |_, _, _| 0.0,
            |k, r| if k >= 200 { r + 0.2 } else { r },
        );
        assert_eq!(
            fault,
            Some((
                200,
                EncoderFault {
                    axis: 0,
                    kind: EncoderFaultKind::Speed
                }
            ))
        );
        let mut c = EncoderCheck::new([0.0; 2], [COUNT_RAD; 2]);
        let e = c.check([0.0, f32::NAN], [0.0; 2], &EncoderLimits::default(), DT_S);
        assert_eq!(
            e,
            Err(EncoderFault {
                axis: 1,
                kind: EncoderFaultKind::NonFinite
            })
        );
    }

    /// The stated detection times: a reading frozen at rest, under a constant torque: the
    /// sample n with a·(n·dt)²/2 > stuck_motion.
    #[test]
    fn a_still_reading_under_torque_is_stuck_within_the_stated_time() {
        let l = EncoderLimits::default();
        for (torque, samples) in [(8.0f32, 1usize), (1.0, 2), (0.5, 3)] {
            let a = (torque - l.hold_torque_nm) / l.max_inertia_kg_m2;
            let stated = (1..)
                .find(|&n: &usize| a * (n as f32 * DT_S).powi(2) / 2.0 > l.stuck_motion_rad)
                .unwrap();
            assert_eq!(stated, samples, "{torque} N·m");
            let mut c = EncoderCheck::new([0.5, 0.5], [COUNT_RAD; 2]);
            let mut found = None;
            for k in 1..100 {
                if let Err(f) = c.check([0.5, 0.5], [0.0, -torque], &l, DT_S) {
                    found = Some((k, f));
                    break;
                }
            }
            assert_eq!(
                found,
                Some((
                    samples,
                    EncoderFault {
                        axis: 1,
                        kind: EncoderFaultKind::Stuck
                    }
                )),
                "{torque} N·m"
            );
        }
    }

    /// A blocked axis (it does not move at all) under a servo-like rising torque is stuck; the
    /// same axis free moves and is not.
    #[test]
    fn a_blocked_axis_is_stuck_and_a_free_one_is_not() {
        // The torque rises by 0.05 N·m per sample, as a servo's does when its reference runs
        // away from a reading that does not follow: the torque acting at sample k is
        // 0.05·(k-1), past hold_torque from sample 6 on.
        let ramp = |k: usize, _: f32, _: f32| (k as f32 * 0.05).min(8.0);
        assert_eq!(
            run(60, 2.2e-3, 0.03, ramp, |_, r| r),
            None,
            "free: it moves"
        );
        let blocked = run(100, 2.2e-3, 0.03, ramp, |_, _| quantise(0.9));
        // Expected motion after m samples of excess 0.05·j N·m (j = 1..m) over 3e-3 kg·m²:
        // dt²·16.7·m³/6 rad roughly, past 1e-4 at m = 5: sample 10.
        assert_eq!(
            blocked,
            Some((
                10,
                EncoderFault {
                    axis: 0,
                    kind: EncoderFaultKind::Stuck
                }
            ))
        );
    }

    #[test]
    fn holding_a_load_within_hold_torque_and_reversing_torque_are_not_stuck() {
        let l = EncoderLimits::default();
        let mut c = EncoderCheck::new([0.5, 0.5], [COUNT_RAD; 2]);
        for k in 0..10_000 {
            // A static load held with 0.19 N·m; axis 2 alternates ±0.5 N·m every sample (a
            // chattering servo at rest: never one sign long enough to move).
            let t2 = if k % 2 == 0 { 0.5 } else { -0.5 };
            assert_eq!(
                c.check([0.5, 0.5], [0.19, t2], &l, DT_S),
                Ok(()),
                "sample {k}"
            );
        }
    }

    /// A coarse encoder (4096 counts/rev on a direct-drive joint: 1.53 mrad per count, more than
    /// one sample's acceleration bound of 1.5 mrad) reads its quantisation neither as a glitch
    /// nor, slowly starting under torque, as a stuck axis; a glitch of a few counts and a stuck
    /// reading are still found.
    #[test]
    fn a_coarse_encoders_quantisation_is_not_a_fault_but_a_glitch_still_is() {
        let count = core::f32::consts::TAU / 4096.0;
        assert_eq!(
            run_with(count, 4000, 2.2e-3, 0.18, reversing_torque_nm, |_, r| r),
            None
        );
        // 0.5 N·m from rest: the expected motion passes stuck_motion (1e-4 rad) long before the
        // axis has moved one count.
        assert_eq!(
            run_with(count, 400, 2.2e-3, 0.03, |_, _, _| 0.5, |_, r| r),
            None
        );
        let glitch = run_with(
            count,
            600,
            2.2e-3,
            0.03,
            |_, _, _| 0.2,
            |k, r| if k == 400 { r + 4.0 * count } else { r },
        );
        assert!(
            matches!(
                glitch,
                Some((
                    400,
                    EncoderFault {
                        axis: 0,
                        kind: EncoderFaultKind::Acceleration
                    }
                ))
            ),
            "{glitch:?}"
        );
        let stuck = run_with(
            count,
            400,
            2.2e-3,
            0.03,
            |_, _, _| 0.5,
            |_, _| quantise_to(0.9, count),
        );
        assert!(
            matches!(
                stuck,
                Some((
                    _,
                    EncoderFault {
                        axis: 0,
                        kind: EncoderFaultKind::Stuck
                    }
                ))
            ),
            "{stuck:?}"
        );
    }

    /// Axis 1 of the co-simulated paper six-bar (`host-sim commission --qemu --plant paper`)
    /// standing still while axis 2 starts a move at 130 rad/s²: its servo holds the coupling
    /// torque `M₁₂·α₂` (0.26 to 0.31 N·m, the inertia matrix's off-diagonal term is 2.1·10⁻³
    /// kg·m² there) and its reading does not change for 6 samples. Counts (2²⁰ per motor
    /// revolution, gear 10) and the torques the controller commanded, sample by sample. Not
    /// stuck; with no coupling allowed for, the same readings are (the controller faulted at
    /// the last sample).
    #[test]
    fn an_axis_holding_still_while_the_other_accelerates_is_not_stuck() {
        const RECORD: [(i32, i32, f32, f32); 26] = [
            (0, 0, -0.014118, -0.042353),
            (0, 0, -0.014118, -0.042353),
            (0, 0, -0.018824, -0.042353),
            (0, 0, -0.018824, -0.042353),
            (0, -1, -0.018824, -0.103529),
            (0, -10, -0.018824, -0.258824),
            (0, -34, -0.032941, -0.367059),
            (1, -78, -0.032941, -0.475294),
            (3, -151, -0.061176, -0.616471),
            (8, -259, -0.084706, -0.696471),
            (12, -406, -0.192941, -0.804706),
            (15, -598, -0.202353, -0.950588),
            (15, -844, -0.244706, -1.068235),
            (15, -1147, -0.216471, -1.077647),
            (15, -1506, -0.249412, -1.04),
            (15, -1919, -0.272941, -1.016471),
            (15, -2387, -0.282353, -1.021176),
            (15, -2907, -0.301176, -0.983529),
            (14, -3481, -0.310588, -1.030588),
            (12, -4108, -0.287059, -1.030588),
            (12, -4791, -0.263529, -1.063529),
            (12, -5530, -0.296471, -1.030588),
            (12, -6321, -0.287059, -0.988235),
            (12, -7165, -0.277647, -1.04),
            (12, -8065, -0.268235, -1.058824),
            (12, -9019, -0.263529, -1.016471),
        ];
        let count = core::f32::consts::TAU / (1_048_576.0 * 10.0);
        let start = [0.3f32, -0.4];
        let replay = |limits: &EncoderLimits| {
            let mut c = EncoderCheck::new(start, [count; 2]);
            for (k, &(c1, c2, t1, t2)) in RECORD.iter().enumerate() {
                let read = [start[0] + c1 as f32 * count, start[1] + c2 as f32 * count];
                c.check(read, [t1, t2], limits, DT_S).map_err(|f| (k, f))?;
            }
            Ok(())
        };
        assert_eq!(replay(&EncoderLimits::default()), Ok(()));
        let uncoupled = EncoderLimits {
            max_coupling_inertia_kg_m2: 0.0,
            max_velocity_product_kg_m2: 0.0,
            ..EncoderLimits::default()
        };
        assert_eq!(
            replay(&uncoupled),
            Err((
                25,
                EncoderFault {
                    axis: 0,
                    kind: EncoderFaultKind::Stuck
                }
            ))
        );
    }

    /// Two coupled axes (the paper machine's inertia matrix: 7.4·10⁻³ on the diagonal,
    /// 2.42·10⁻³ coupling, velocity products up to 3.72·10⁻³): axis 2 runs a 5 g-like bang-bang (±400 rad/s², up to 10 rad/s) while
    /// axis 1's servo holds it still with exactly the coupling and velocity-product torques.
    /// Not stuck. Axis 1's encoder frozen while its own reference moves off (the servo's
    /// torque ramping 0.05 N·m per sample on top of the holding torque) is still found, within
    /// the samples stated.
    #[test]
    fn coupled_axes_hold_without_a_stuck_finding_and_a_frozen_one_is_still_found() {
        let (m12, m22, c) = (2.42e-3f32, 7.4e-3f32, 3.72e-3f32);
        let l = EncoderLimits::default();
        let run = |ramp_nm: f32, samples: usize| {
            let (mut a2, mut w2) = (-0.4f32, 0.0f32);
            let mut c_check = EncoderCheck::new([0.3, a2], [COUNT_RAD; 2]);
            for k in 0..samples {
                // Axis 2's acceleration: +400 rad/s² for 25 ms, then -400, repeating.
                let alpha2 = if (k / 50) % 2 == 0 { 400.0 } else { -400.0 };
                // The torques that keep axis 1 still; axis 1's reading does not change (held
                // still, or frozen while the servo's torque ramps).
                let hold1 = m12 * alpha2 + c * w2 * w2 + ramp_nm * k as f32;
                let tau2 = m22 * alpha2;
                // Exact for the constant acceleration over the sample.
                a2 += (w2 + 0.5 * alpha2 * DT_S) * DT_S;
                w2 += alpha2 * DT_S;
                let read = [0.3, quantise(a2)];
                if let Err(f) = c_check.check(read, [hold1, tau2], &l, DT_S) {
                    return Some((k, f));
                }
            }
            None
        };
        assert_eq!(run(0.0, 2000), None);
        let frozen = run(0.05, 2000).expect("a frozen encoder is found");
        assert_eq!(frozen.1.axis, 0);
        assert_eq!(frozen.1.kind, EncoderFaultKind::Stuck);
        assert!(frozen.0 <= 25, "found after {} samples", frozen.0);
        println!("frozen under coupling: found after {} samples", frozen.0);
    }

    #[test]
    fn limits_validate() {
        assert_eq!(EncoderLimits::default().validate(), Ok(()));
        let l = EncoderLimits {
            hold_torque_nm: f32::NAN,
            ..EncoderLimits::default()
        };
        assert_eq!(l.validate(), Err("encoder_limits.hold_torque_nm"));
        let l = EncoderLimits {
            max_accel_rad_s2: -1.0,
            ..EncoderLimits::default()
        };
        assert_eq!(l.validate(), Err("encoder_limits.max_accel_rad_s2"));
    }
}
