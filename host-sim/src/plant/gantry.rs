//! The gantry in simulation: each axis a rigid moving mass with Coulomb friction (a smooth
//! sign over ±2 mm/s), driven by
//! its drive's position loop (PID at the configured bandwidth) with feed-forward of the
//! reference's acceleration (with the configured mass error) and of 90 % of the friction, read
//! by a linear scale of the configured resolution. What it leaves is the following error the
//! micro compensates (`execute`).
//!
//! The loop: at each sample the drive reads the scale, computes the force (held over the
//! sample, as the micro's torque is) and the axis is integrated over the sample in
//! [`SUBSTEPS`] semi-implicit steps. Gains from the bandwidth `ω` and the moving mass `m`, as
//! the micro's servo has them: `kp = m·ω²`, `kd = 2·0.7·m·ω`, `ki = kp·ω/4`.
//!
//! Not modelled: the bridge's first mode (a real gantry's scale sees the carriage, not the
//! head; a mode the scale does not see stays in the contour), cogging, thermal drift.

use crate::gantry_spec::GantrySpec;

/// Integration steps per sample.
pub const SUBSTEPS: u32 = 10;
/// The speed over which the Coulomb friction turns over at a reversal (mm/s): a smooth sign,
/// the drives' feed-forward the same.
const FRICTION_SPEED_MM_S: f64 = 2.0;
/// Share of the friction the drives feed forward.
const FRICTION_FF_SHARE: f64 = 0.9;

/// The reference of one axis at one sample.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct AxisReference {
    pub position_mm: f64,
    pub velocity_mm_s: f64,
    pub accel_mm_s2: f64,
}

/// One axis and its drive.
#[derive(Clone, Debug)]
struct Axis {
    mass_kg: f64,
    friction_n: f64,
    kp_n_per_mm: f64,
    kd_n_s_per_mm: f64,
    ki_n_per_mm_s: f64,
    ff_mass_kg: f64,
    resolution_mm: f64,
    integral_n: f64,
    integral_limit_n: f64,
    last_measured_mm: f64,
    position_mm: f64,
    velocity_mm_s: f64,
    force_n: f64,
}

impl Axis {
    fn measured_mm(&self) -> f64 {
        if self.resolution_mm > 0.0 {
            (self.position_mm / self.resolution_mm).round() * self.resolution_mm
        } else {
            self.position_mm
        }
    }

    fn friction_force_n(&self, v: f64) -> f64 {
        self.friction_n * (v / FRICTION_SPEED_MM_S).tanh()
    }

    fn step(&mut self, r: &AxisReference, dt: f64) {
        let meas = self.measured_mm();
        let e = r.position_mm - meas;
        let v_meas = (meas - self.last_measured_mm) / dt;
        self.last_measured_mm = meas;
        self.integral_n = (self.integral_n + self.ki_n_per_mm_s * e * dt)
            .clamp(-self.integral_limit_n, self.integral_limit_n);
        let ff = self.ff_mass_kg * r.accel_mm_s2 * 1e-3
            + FRICTION_FF_SHARE * self.friction_n * (r.velocity_mm_s / FRICTION_SPEED_MM_S).tanh();
        // The backward difference is the velocity half a sample ago: compare like with like.
        let v_ref = r.velocity_mm_s - 0.5 * dt * r.accel_mm_s2;
        self.force_n =
            self.kp_n_per_mm * e + self.kd_n_s_per_mm * (v_ref - v_meas) + self.integral_n + ff;
        let h = dt / f64::from(SUBSTEPS);
        for _ in 0..SUBSTEPS {
            let acc =
                (self.force_n - self.friction_force_n(self.velocity_mm_s)) / self.mass_kg * 1e3;
            self.velocity_mm_s += acc * h;
            self.position_mm += self.velocity_mm_s * h;
        }
    }
}

/// The two axes of the gantry.
#[derive(Clone, Debug)]
pub struct Gantry {
    axes: [Axis; 2],
    dt_s: f64,
}

impl Gantry {
    /// The gantry of `spec` at rest at `at_mm`, stepped every `dt_s`.
    pub fn new(spec: &GantrySpec, at_mm: [f64; 2], dt_s: f64) -> Gantry {
        let w = std::f64::consts::TAU * spec.bandwidth_hz;
        let axis = |k: usize| {
            let m = spec.moving_mass_kg[k];
            let kp = m * w * w * 1e-3;
            Axis {
                mass_kg: m,
                friction_n: spec.friction_n[k],
                kp_n_per_mm: kp,
                kd_n_s_per_mm: 2.0 * 0.7 * m * w * 1e-3,
                ki_n_per_mm_s: kp * w / 4.0,
                ff_mass_kg: m * (1.0 + spec.feedforward_mass_error_pct / 100.0),
                resolution_mm: spec.scale_resolution_um * 1e-3,
                integral_n: 0.0,
                integral_limit_n: 2.0 * spec.friction_n[k] + 0.1 * m,
                last_measured_mm: at_mm[k],
                position_mm: at_mm[k],
                velocity_mm_s: 0.0,
                force_n: 0.0,
            }
        };
        let mut g = Gantry {
            axes: [axis(0), axis(1)],
            dt_s,
        };
        for a in &mut g.axes {
            a.last_measured_mm = a.measured_mm();
        }
        g
    }

    /// What the scales read (mm): what the drives and the micro see.
    pub fn measured_mm(&self) -> [f64; 2] {
        [self.axes[0].measured_mm(), self.axes[1].measured_mm()]
    }

    /// Where the axes really are (mm).
    pub fn position_mm(&self) -> [f64; 2] {
        [self.axes[0].position_mm, self.axes[1].position_mm]
    }

    /// Their real velocities (mm/s).
    pub fn velocity_mm_s(&self) -> [f64; 2] {
        [self.axes[0].velocity_mm_s, self.axes[1].velocity_mm_s]
    }

    /// The drives' forces of the last sample (N).
    pub fn force_n(&self) -> [f64; 2] {
        [self.axes[0].force_n, self.axes[1].force_n]
    }

    /// One sample: each drive reads its scale, computes its force for `reference`, and the
    /// axes move for one sample period.
    pub fn step(&mut self, reference: &[AxisReference; 2]) {
        let dt = self.dt_s;
        for (a, r) in self.axes.iter_mut().zip(reference) {
            a.step(r, dt);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 g move: the following error is the feed-forward's mass error over the loop's
    /// stiffness (5 % of 1 g over ω²: about 14 µm), and it settles.
    #[test]
    fn following_error_of_a_1g_move_is_the_mass_error_over_the_stiffness() {
        let spec = GantrySpec::paper();
        let dt = 5e-4;
        let mut g = Gantry::new(&spec, [100.0, 100.0], dt);
        let a = 9806.65;
        let w = std::f64::consts::TAU * spec.bandwidth_hz;
        let mut worst = 0.0f64;
        // Accelerate for 0.1 s, decelerate for 0.1 s, rest 0.3 s (a jerk-free bang-bang: the
        // worst case of the step in acceleration).
        for k in 0..1000 {
            let t = k as f64 * dt;
            let (p, v, acc) = if t < 0.1 {
                (0.5 * a * t * t, a * t, a)
            } else if t < 0.2 {
                let u = t - 0.1;
                (
                    0.5 * a * 0.01 + a * 0.1 * u - 0.5 * a * u * u,
                    a * (0.1 - u),
                    -a,
                )
            } else {
                (a * 0.01, 0.0, 0.0)
            };
            let r = AxisReference {
                position_mm: 100.0 + p,
                velocity_mm_s: v,
                accel_mm_s2: acc,
            };
            g.step(&[r, r]);
            let e = (r.position_mm + v * dt + 0.5 * acc * dt * dt - g.position_mm()[0]).abs();
            worst = worst.max(e);
        }
        let want = 0.05 * a / (w * w);
        assert!(
            worst > 0.3 * want && worst < 5.0 * want,
            "{worst} mm vs {want}"
        );
        let end = 100.0 + a * 0.01;
        assert!(
            (g.position_mm()[0] - end).abs() < 2e-4,
            "{:?}",
            g.position_mm()
        );
        assert!((g.position_mm()[1] - end).abs() < 2e-4);
    }
}
