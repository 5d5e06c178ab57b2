//! When is the machine at rest, so that the instrument's reading and the encoder angles belong
//! together? The criterion of a measurement session, on the servo's own samples (the link's
//! telemetry, or a simulation's).
//!
//! **Settled** at sample k: over the window of the last [`SettleCriterion::dwell_s`] ending at
//! k (at least two samples spanning it),
//! * every sample's following error (|reference − encoder|, the larger axis) is at most
//!   [`SettleCriterion::following_error_rad`], and
//! * each encoder moved at most [`SettleCriterion::speed_rad_s`] × dwell between the window's
//!   first and last sample (its mean speed: one encoder count of dither does not count as
//!   motion, a creep does).
//!
//! The defaults, and why: 2 µrad of following error is 0.3-0.4 µm at the tool (the hidden
//! robot's Jacobian is 150-200 mm/rad), below the 1 µm instrument; a mean speed of 20 µrad/s
//! over 0.1 s is 2 µrad (0.4 µm) of drift at most while the instrument reads; 0.1 s is ten
//! samples at the link's fastest telemetry (2 kHz / 20). A machine that is not settled
//! [`SettleCriterion::timeout_s`] after its move ended is an error (a servo that hunts, a
//! drive that creeps), never a reading taken anyway.
//!
//! Cost: one pass over the window per sample.

use serde::Serialize;

/// The settle criterion (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SettleCriterion {
    /// Largest following error of either axis allowed in the window (rad).
    pub following_error_rad: f64,
    /// Largest mean encoder speed over the window (rad/s).
    pub speed_rad_s: f64,
    /// The window's length (s).
    pub dwell_s: f64,
    /// Longest wait after the move ends (s, machine time).
    pub timeout_s: f64,
}

impl Default for SettleCriterion {
    fn default() -> Self {
        SettleCriterion {
            following_error_rad: 2e-6,
            speed_rad_s: 2e-5,
            dwell_s: 0.1,
            timeout_s: 3.0,
        }
    }
}

impl SettleCriterion {
    /// Refuses thresholds that are no thresholds (not positive, not finite).
    pub fn check(&self) -> Result<(), String> {
        for (name, v) in [
            ("following error", self.following_error_rad),
            ("speed", self.speed_rad_s),
            ("dwell", self.dwell_s),
            ("timeout", self.timeout_s),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(format!(
                    "the settle criterion's {name} must be a positive number, not {v}"
                ));
            }
        }
        if self.timeout_s < self.dwell_s {
            return Err(format!(
                "the settle timeout {} s is shorter than the dwell {} s",
                self.timeout_s, self.dwell_s
            ));
        }
        Ok(())
    }
}

/// One servo sample as the criterion sees it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ServoSample {
    /// Machine time (s).
    pub t_s: f64,
    /// Commanded encoder angles (rad).
    pub reference_rad: [f64; 2],
    /// Encoder angles (rad).
    pub encoder_rad: [f64; 2],
    /// The larger axis' |reference − encoder| (rad).
    pub following_error_rad: f64,
}

/// The first sample (index into `samples`, time-ordered) at which the machine is settled by
/// `c`, looking only at samples from `from_s` on (the move's end). `None`: not yet.
pub fn settled_at(samples: &[ServoSample], from_s: f64, c: &SettleCriterion) -> Option<usize> {
    let first = samples.iter().position(|s| s.t_s >= from_s)?;
    let mut start = first;
    for k in first..samples.len() {
        let now = samples[k];
        // The window's first sample: the latest one at least `dwell` before `now`.
        while start < k && now.t_s - samples[start + 1].t_s >= c.dwell_s {
            start += 1;
        }
        let w = &samples[start..=k];
        if now.t_s - samples[start].t_s < c.dwell_s - 1e-9 || w.len() < 2 {
            continue;
        }
        let quiet = w
            .iter()
            .all(|s| s.following_error_rad <= c.following_error_rad);
        let span = now.t_s - samples[start].t_s;
        let still = (0..2).all(|j| {
            (now.encoder_rad[j] - samples[start].encoder_rad[j]).abs() <= c.speed_rad_s * span
        });
        if quiet && still {
            return Some(k);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A settling axis: an exponential approach to `goal` with time constant `tau`, encoder
    /// quantised to `count` rad, sampled every `dt`.
    fn settling(goal: f64, tau: f64, count: f64, dt: f64, n: usize) -> Vec<ServoSample> {
        (0..n)
            .map(|i| {
                let t = i as f64 * dt;
                let e = goal - 1e-4 * (-t / tau).exp();
                let q = (e / count).round() * count;
                ServoSample {
                    t_s: t,
                    reference_rad: [goal; 2],
                    encoder_rad: [q; 2],
                    following_error_rad: (goal - q).abs(),
                }
            })
            .collect()
    }

    #[test]
    fn settles_once_the_error_is_small_for_the_dwell() {
        let c = SettleCriterion::default();
        let s = settling(0.8, 0.02, 6e-7, 0.01, 100);
        let k = settled_at(&s, 0.0, &c).expect("settles");
        // 1e-4·exp(−t/0.02) ≤ 2e-6 from t = 0.078 s on; the window of 0.1 s after that.
        assert!(
            (0.17..0.25).contains(&s[k].t_s),
            "settled at {} s",
            s[k].t_s
        );
        // Not before the move's end.
        let k2 = settled_at(&s, 0.5, &c).unwrap();
        assert!(s[k2].t_s >= 0.5 + c.dwell_s - 1e-9);
    }

    #[test]
    fn a_creeping_or_hunting_axis_never_settles() {
        let c = SettleCriterion::default();
        // Creep: the reference moves 50 µrad/s and the encoder follows it exactly.
        let creep: Vec<ServoSample> = (0..300)
            .map(|i| {
                let t = i as f64 * 0.01;
                let p = 0.5 + 5e-5 * t;
                ServoSample {
                    t_s: t,
                    reference_rad: [p; 2],
                    encoder_rad: [p; 2],
                    following_error_rad: 0.0,
                }
            })
            .collect();
        assert_eq!(settled_at(&creep, 0.0, &c), None);
        // Hunting: ±3 µrad about the reference.
        let hunt: Vec<ServoSample> = (0..300)
            .map(|i| ServoSample {
                t_s: i as f64 * 0.01,
                reference_rad: [0.5; 2],
                encoder_rad: [0.5 + 3e-6 * (i as f64).sin(); 2],
                following_error_rad: 3e-6 * (i as f64).sin().abs(),
            })
            .collect();
        assert_eq!(settled_at(&hunt, 0.0, &c), None);
        assert!(SettleCriterion {
            dwell_s: f64::NAN,
            ..c
        }
        .check()
        .is_err());
    }
}
