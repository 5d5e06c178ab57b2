//! Disturbance observer of one axis: estimates the torque the feed-forward gets wrong from the
//! measured motion, so the servo adds it before the PID has to lag to find it (the following
//! error at 5 g with every mass and inertia of the fed-forward model 20 % off).
//!
//! The estimate is *added* to the torque: a disturbance `Δ` the feed-forward lacks is answered
//! by `+Δ̂`, and `tests/disturbance_observer.rs` checks the sign on a simple plant (a constant
//! torque disturbance estimated with its sign and cancelled).
//!
//! # Why
//! With a model error δ the feed-forward leaves `δ·J·θ̈` of torque to the feedback, which the
//! PID rejects only by lagging, about `δ·θ̈/ω²` at its bandwidth ω; ω (1000 rad/s) is at its
//! limit for the 0.5 ms sample, so more gain is no remedy. The observer measures that remainder
//! from the joint's response and feeds it forward one sample later, filtered at its own
//! bandwidth `g`: what the PID is left with is the remainder's change within about `1/g` plus
//! a sample and a half, a factor `s/(s + g)` on its spectrum.
//!
//! # What it estimates
//! In the error space of the feed-forward: with `e = θ_ref - θ` (the following error) and
//! `τ_fb` the torque applied beyond the feed-forward (PID and the observer's own, after the
//! limit), a rigid axis of inertia `J_n` obeys `J_n·ë = Δ - τ_fb`, where `Δ` is what the
//! feed-forward lacks (mass and inertia error, unmodelled friction). Over the samples, with the
//! torque held over each period and the velocity error `ė_k = (e_k - e_(k-1))/dt` a mean over
//! the last period (as the servo computes it), exactly for a constant `Δ`:
//!
//! ```text
//! Δ_k = J_n·(ė_k - ė_(k-1))/dt + (τ_fb,(k-1) + τ_fb,(k-2))/2        (centred at t_(k-1))
//! Δ̂_k = Δ̂_(k-1) + α·(Δ_k - Δ̂_(k-1)),   α = g·dt/(1 + g·dt)           (first-order low pass)
//! ```
//! When the feed-forward is right and the axis on its reference, `e` and `τ_fb` stay zero and
//! so does the estimate: the identified model's accuracy is kept. A nominal inertia `J_n` off
//! the axis' true `J` leaves `(J_n/J - 1)` of the axis' own acceleration error in the loop,
//! stable for `J_n < 2·J` (small gain); the default is the identified diagonal, 7.4e-3 kg·m².
//!
//! # Noise
//! The second difference of the encoder sees its quantisation `q` as up to `4·q/dt²` of
//! acceleration; the low pass takes it down by about `α` (and more, as the differenced noise
//! is high-pass). The paper plant's encoders (2^20 counts per motor turn, gear 10: 0.6 µrad):
//! see the torque RMS at rest in README ("Why a 20 % mass error ...").
//!
//! # Cost
//! Per axis per sample: 5 multiplications, 6 additions, a limit (two comparisons), three
//! floats of state; no division (`J_n/dt` and `α` are computed once, [`ObserverCoefficients`]).
//! `cargo qemu-bench` `servo_step_motion` includes it (README's cycle table).
//!
//! No panic, no NaN out: the estimate goes through [`saturate`] to the axis' torque limit (a
//! NaN becomes zero), and the settings are checked by `AxisGains::validate`.

use crate::pid::saturate;

/// The observer's settings turned into what a sample needs (computed once, with divisions).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ObserverCoefficients {
    /// `α = g·dt/(1 + g·dt)`: 0 turns the observer off.
    pub alpha: f32,
    /// `J_n/dt` (N·m·s/rad): the nominal inertia times the sample rate.
    pub inertia_rate_nm_s_per_rad: f32,
}

impl ObserverCoefficients {
    /// For a bandwidth `bandwidth_rad_s` (0: off), a nominal inertia `inertia_kg_m2` and a sample
    /// period `dt_s`. Settings a servo refuses (negative, NaN, infinite) give an observer that
    /// is off.
    pub fn new(bandwidth_rad_s: f32, inertia_kg_m2: f32, dt_s: f32) -> Self {
        let gdt = bandwidth_rad_s * dt_s;
        let valid = gdt.is_finite()
            && gdt >= 0.0
            && inertia_kg_m2.is_finite()
            && inertia_kg_m2 >= 0.0
            && dt_s > 0.0;
        if !valid {
            return ObserverCoefficients::default();
        }
        let inertia_rate = inertia_kg_m2 / dt_s;
        ObserverCoefficients {
            alpha: gdt / (1.0 + gdt),
            inertia_rate_nm_s_per_rad: if inertia_rate.is_finite() {
                inertia_rate
            } else {
                0.0
            },
        }
    }
}

/// The state of one axis' observer: the estimate and the last two samples it needs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DisturbanceObserver {
    /// `Δ̂` (N·m): the torque added to the feed-forward.
    estimate_nm: f32,
    /// `ė_(k-1)` (rad/s).
    last_velocity_error_rad_s: f32,
    /// `τ_fb,(k-1)` and `τ_fb,(k-2)` (N·m).
    last_feedback_nm: [f32; 2],
    /// The encoder reading of the sample it last ran on (rad): when the previous sample's
    /// differs, samples without the observer came between (see [`DisturbanceObserver::is_current`]).
    last_encoder_rad: f32,
}

impl DisturbanceObserver {
    /// The estimate for this sample (N·m, within `±limit_nm`) from the velocity error
    /// `ė_k`; call [`DisturbanceObserver::applied`] with the sample's torque afterwards.
    /// While the reference stands still (`moving` false) the estimate decays to zero at the
    /// same rate: there is no feed-forward to correct, and an axis stuck in its friction looks
    /// to the observer like a disturbance equal to the feedback, which it would integrate on
    /// top of the PID's integrator (a second integrator: hunting of a few encoder counts at
    /// rest, measured on the paper plant). At rest the PID holds the static load, as without
    /// an observer.
    #[inline(always)]
    pub fn estimate_nm(
        &mut self,
        c: &ObserverCoefficients,
        velocity_error_rad_s: f32,
        limit_nm: f32,
        moving: bool,
    ) -> f32 {
        let [f1, f2] = self.last_feedback_nm;
        let raw = c.inertia_rate_nm_s_per_rad
            * (velocity_error_rad_s - self.last_velocity_error_rad_s)
            + (f1 + f2) * 0.5;
        self.last_velocity_error_rad_s = velocity_error_rad_s;
        let target = if moving { raw } else { 0.0 };
        let e = self.estimate_nm;
        self.estimate_nm = saturate(e + c.alpha * (target - e), limit_nm);
        self.estimate_nm
    }

    /// Records the torque applied beyond the feed-forward in this sample (N·m: the command
    /// after the limit minus the model's feed-forward).
    #[inline(always)]
    pub fn applied(&mut self, feedback_nm: f32) {
        self.last_feedback_nm = [feedback_nm, self.last_feedback_nm[0]];
    }

    /// Restarts from a sample without an observer (the servo's difference path): no estimate,
    /// this sample's velocity error and feedback as the history.
    #[inline(always)]
    pub fn restart(&mut self, velocity_error_rad_s: f32, feedback_nm: f32) {
        *self = DisturbanceObserver {
            estimate_nm: 0.0,
            last_velocity_error_rad_s: velocity_error_rad_s,
            last_feedback_nm: [feedback_nm; 2],
            last_encoder_rad: self.last_encoder_rad,
        };
    }

    /// Whether its history is the previous sample's: the encoder reading it last ran on is the
    /// previous sample's. Otherwise samples without the observer came between (the servo's plain
    /// step, an engage) and it must [`restart`](Self::restart). Why a reading and not a flag the
    /// plain step clears: the plain step then pays nothing for the observer. A gap
    /// of plain samples that leaves the reading exactly where it was is a machine at rest, where
    /// the estimate has decayed and the history is what the observer would have seen.
    #[inline(always)]
    pub fn is_current(&self, previous_encoder_rad: f32) -> bool {
        self.last_encoder_rad == previous_encoder_rad
    }

    /// Records the encoder reading of this sample (after [`DisturbanceObserver::applied`]).
    #[inline(always)]
    pub fn ran_at(&mut self, encoder_rad: f32) {
        self.last_encoder_rad = encoder_rad;
    }

    /// The current estimate (N·m).
    pub fn current_nm(&self) -> f32 {
        self.estimate_nm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rigid axis of inertia J with a constant unmodelled torque, a P-D feedback: the
    /// estimate converges to the disturbance at the observer's bandwidth, and the feedback's
    /// share goes to zero.
    #[test]
    fn estimates_a_constant_torque_error_of_a_rigid_axis() {
        let (j, dt, d) = (7.4e-3f64, 5e-4f64, 0.7f64);
        let c = ObserverCoefficients::new(300.0, j as f32, dt as f32);
        let mut obs = DisturbanceObserver::default();
        // Reference at rest at 0; the axis' state, exact integration of a held torque.
        let (mut theta, mut omega) = (0.0f64, 0.0f64);
        let (mut e_last, mut tau_fb) = (0.0f64, 0.0f64);
        let (kp, kd) = (7400.0, 10.36);
        for k in 0..400 {
            let e = -theta;
            let de = (e - e_last) / dt;
            e_last = e;
            let est = obs.estimate_nm(&c, de as f32, 8.0, true) as f64;
            if k > 0 {
                tau_fb = kp * e + kd * de + est;
            }
            obs.applied(tau_fb as f32);
            // Plant: J θ̈ = τ_fb - Δ (the feed-forward lacks Δ; the reference is at rest).
            let acc = (tau_fb - d) / j;
            theta += omega * dt + 0.5 * acc * dt * dt;
            omega += acc * dt;
        }
        assert!(
            (obs.current_nm() as f64 - d).abs() < 1e-3 * d,
            "{}",
            obs.current_nm()
        );
        // The feedback's own share (kp·e) is gone: the axis sits on its reference.
        assert!(theta.abs() < 1e-7, "{theta}");
    }

    #[test]
    fn off_or_refused_settings_estimate_nothing_and_nan_is_contained() {
        for (g, j, dt) in [
            (0.0, 7.4e-3, 5e-4),
            (f32::NAN, 7.4e-3, 5e-4),
            (-1.0, 7.4e-3, 5e-4),
            (300.0, f32::INFINITY, 5e-4),
            (300.0, 7.4e-3, 0.0),
        ] {
            let c = ObserverCoefficients::new(g, j, dt);
            assert_eq!(c.alpha, 0.0, "{g} {j} {dt}");
            let mut obs = DisturbanceObserver::default();
            obs.applied(1.0);
            assert_eq!(obs.estimate_nm(&c, 3.0, 8.0, true), 0.0);
        }
        let c = ObserverCoefficients::new(300.0, 7.4e-3, 5e-4);
        assert_eq!(
            DisturbanceObserver::default().estimate_nm(&c, f32::NAN, 8.0, true),
            0.0
        );
        assert_eq!(
            DisturbanceObserver::default().estimate_nm(&c, 1e30, 8.0, true),
            8.0
        );
        assert_eq!(
            DisturbanceObserver::default().estimate_nm(&c, -1e30, 8.0, true),
            -8.0
        );
        assert_eq!(
            DisturbanceObserver::default().estimate_nm(&c, 1.0, f32::NAN, true),
            0.0
        );
    }
}
