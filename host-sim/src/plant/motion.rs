//! The plant's equations of motion: both drives coupled through the linkage's inertia.
//!
//! ```text
//! (diag(J_rotor) + M(θ_link))·θ̈ + h(θ_link, θ̇) + b·θ̇ + τc·sgn(θ̇) + cog(θ) = k·limit(τ)
//! ```
//! `J_rotor` is each drive's motor and gearbox inertia at the joint, `M` and `h` the six-bar's
//! bodies (`linkage`), `b` and `τc` the drives' viscous and Coulomb friction, `cog` their
//! cogging (periodic in the motor angle, taken at each substep's start), `limit` the
//! amplifiers' torque limit and `k` the motors' torque constant relative to the nominal. The backlash is kinematic (`drive`): the link angle lags the motor
//! by the play, and the linkage's inertia acts on the motor as if the gear were stiff (crossing
//! the 20 µrad play takes well under a millisecond at speed; the link's coasting meanwhile is not
//! modelled).
//!
//! Integration: the linkage's inertia matrix and velocity-product coefficients are evaluated
//! once per call ([`CoupledDrives::advance`], one servo sample) at the configuration predicted
//! for the middle of the sample (`θ + θ̇·dt/2`): they change with the configuration, which moves
//! by ~2.5 mrad in half a sample at 10 rad/s, so the midpoint makes the error second order,
//! ~1e-7 of the torques. Inside, classical Runge–Kutta (4th order) per substep with the
//! velocity products (a quadratic form in `θ̇`) and the friction evaluated at every stage, the
//! friction's direction fixed over the substep. Coulomb friction stops an axis, it does not
//! reverse it within a substep; an axis at rest stays stuck while the torque it needs to stay
//! there (the other axis moving) is within its Coulomb friction.
//!
//! Cost: one `Linkage::inertia_and_coriolis` (five torque evaluations, one FK) per sample and a
//! few dozen flops per substep: ~1 µs per 2 kHz sample on the host, against the six-bar
//! equilibrium solve's ~5 µs.

use crate::plant::linkage::{InertiaAt, Linkage};
use crate::plant::Drive;
use kinematics_core::jacobian::Mat2;
use kinematics_core::KinematicsError;

/// The total inertia of both drives over one sample: the linkage's plus the rotors', with its
/// inverse (the substeps only multiply).
struct Inertia {
    linkage: InertiaAt,
    total: Mat2<f64>,
    inverse: Mat2<f64>,
}

impl Inertia {
    /// The accelerations for the net torques `r`, an axis in `stuck` held.
    fn accelerations(&self, r: [f64; 2], stuck: [bool; 2]) -> [f64; 2] {
        let (m, i) = (&self.total, &self.inverse);
        match stuck {
            [true, true] => [0.0; 2],
            [true, false] => [0.0, r[1] / m[1][1]],
            [false, true] => [r[0] / m[0][0], 0.0],
            [false, false] => [
                i[0][0] * r[0] + i[0][1] * r[1],
                i[1][0] * r[0] + i[1][1] * r[1],
            ],
        }
    }
}

/// +1, -1 or 0 (at rest).
fn direction(w: f64) -> f64 {
    if w > 0.0 {
        1.0
    } else if w < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// The two drives and the linkage between them.
pub struct CoupledDrives<'a> {
    pub drives: &'a mut [Drive; 2],
    pub linkage: &'a Linkage,
}

impl CoupledDrives<'_> {
    /// The torques left for acceleration at velocities `w`, friction in direction `dir`.
    fn net_torque(&self, inertia: &Inertia, w: [f64; 2], tau: [f64; 2], dir: [f64; 2]) -> [f64; 2] {
        let h = inertia.linkage.bias_nm(w);
        [0, 1].map(|k| {
            let (b, c) = self.drives[k].friction();
            let cogging = self.drives[k].cogging_nm(self.drives[k].motor_rad);
            tau[k] - h[k] - b * w[k] - c * dir[k] - cogging
        })
    }

    /// Advances both drives by `dt_s` in `substeps` steps under the torque commands `torque_nm`.
    pub fn advance(
        &mut self,
        torque_nm: [f64; 2],
        dt_s: f64,
        substeps: u32,
    ) -> Result<(), KinematicsError> {
        let tau = [
            self.drives[0].limit_torque(torque_nm[0]),
            self.drives[1].limit_torque(torque_nm[1]),
        ];
        // The linkage at the middle of the interval.
        let mid =
            [0, 1].map(|k| self.drives[k].link_rad() + 0.5 * dt_s * self.drives[k].velocity_rad_s);
        let linkage = self.linkage.inertia_and_coriolis(mid)?;
        let mut total = linkage.mass_kg_m2;
        for (k, row) in total.iter_mut().enumerate() {
            row[k] += self.drives[k].rotor_inertia_kg_m2();
        }
        let det = total[0][0] * total[1][1] - total[0][1] * total[1][0];
        if !(det > 0.0 && total[0][0] > 0.0) {
            return Err(KinematicsError::NonFinite);
        }
        let inverse = [
            [total[1][1] / det, -total[0][1] / det],
            [-total[1][0] / det, total[0][0] / det],
        ];
        let inertia = Inertia {
            linkage,
            total,
            inverse,
        };
        let h = dt_s / f64::from(substeps.max(1));
        for _ in 0..substeps.max(1) {
            self.substep(&inertia, tau, h)?;
        }
        Ok(())
    }

    fn substep(&mut self, inertia: &Inertia, tau: [f64; 2], h: f64) -> Result<(), KinematicsError> {
        let th = [self.drives[0].motor_rad, self.drives[1].motor_rad];
        let w = [self.drives[0].velocity_rad_s, self.drives[1].velocity_rad_s];
        let coulomb = [self.drives[0].friction().1, self.drives[1].friction().1];
        // Friction directions and stuck axes: a moving axis rubs against its motion; an axis at
        // rest stays stuck while the torque that holds it (the other axis free) is within its
        // Coulomb friction, else it breaks away in the direction of that torque.
        let mut dir = [direction(w[0]), direction(w[1])];
        let mut stuck = [
            w[0] == 0.0 && coulomb[0] > 0.0,
            w[1] == 0.0 && coulomb[1] > 0.0,
        ];
        for _ in 0..3 {
            let r = self.net_torque(inertia, w, tau, dir);
            let a = inertia.accelerations(r, stuck);
            let mut changed = false;
            for k in 0..2 {
                if stuck[k] {
                    let other = 1 - k;
                    let hold = r[k] - inertia.total[k][other] * a[other];
                    if hold.abs() > coulomb[k] {
                        stuck[k] = false;
                        dir[k] = hold.signum();
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        // RK4 on (θ, θ̇) with the stuck axes held and the friction directions fixed.
        let f = |w: [f64; 2]| inertia.accelerations(self.net_torque(inertia, w, tau, dir), stuck);
        let add = |x: [f64; 2], d: [f64; 2], s: f64| [x[0] + d[0] * s, x[1] + d[1] * s];
        let a1 = f(w);
        let w2 = add(w, a1, h / 2.0);
        let a2 = f(w2);
        let w3 = add(w, a2, h / 2.0);
        let a3 = f(w3);
        let w4 = add(w, a3, h);
        let a4 = f(w4);
        for k in 0..2 {
            let angle = th[k] + h / 6.0 * (w[k] + 2.0 * w2[k] + 2.0 * w3[k] + w4[k]);
            let mut velocity = w[k] + h / 6.0 * (a1[k] + 2.0 * a2[k] + 2.0 * a3[k] + a4[k]);
            if stuck[k] {
                velocity = 0.0;
            } else if coulomb[k] > 0.0 && velocity * dir[k] < 0.0 {
                // Coulomb friction stops the axis; whether it moves on is decided next substep.
                velocity = 0.0;
            }
            if !(angle.is_finite() && velocity.is_finite()) {
                return Err(KinematicsError::NonFinite);
            }
            self.drives[k].set_motion(angle, velocity);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::plant::{Plant, PlantConfig};

    fn energy(p: &Plant) -> f64 {
        let w = [p.drives[0].velocity_rad_s, p.drives[1].velocity_rad_s];
        let rotors: f64 = (0..2)
            .map(|k| 0.5 * p.drives[k].rotor_inertia_kg_m2() * w[k] * w[k])
            .sum();
        rotors + p.linkage.kinetic_energy_j(p.link_rad(), w).unwrap()
    }

    fn swinging(cfg: &PlantConfig, w: [f64; 2]) -> Plant {
        let mut p = Plant::new(cfg, 1);
        p.drives[0].set_motion(0.80, w[0]);
        p.drives[1].set_motion(-0.76, w[1]);
        p
    }

    /// No torque, no friction: the machine swings freely and keeps its kinetic energy (the
    /// inertia matrix changes along the way, so the velocities do not).
    #[test]
    fn a_free_swing_keeps_its_energy() {
        let mut p = swinging(&PlantConfig::ideal(), [1.5, -2.0]);
        let e0 = energy(&p);
        let w0 = [p.drives[0].velocity_rad_s, p.drives[1].velocity_rad_s];
        let mut worst = 0.0f64;
        for _ in 0..400 {
            p.advance([0.0; 2], 5e-4, 10).unwrap();
            worst = worst.max((energy(&p) - e0).abs() / e0);
        }
        let w1 = [p.drives[0].velocity_rad_s, p.drives[1].velocity_rad_s];
        eprintln!("free swing 0.2 s: energy {e0:.6e} J, worst relative drift {worst:.2e}; velocities {w0:?} -> {w1:?}");
        // The linkage's inertia is evaluated once per sample at its middle: second order.
        assert!(worst < 1e-7, "{worst}");
        assert!(
            (w1[0] - w0[0]).abs() > 1e-3,
            "the coupling changed the velocities: {w1:?}"
        );
        // With the linkage's bodies left out the velocities would not change at all.
        let mut cfg = PlantConfig::ideal();
        cfg.linkage = crate::plant::config::LinkageConfig::massless();
        let mut q = swinging(&cfg, [1.5, -2.0]);
        for _ in 0..400 {
            q.advance([0.0; 2], 5e-4, 10).unwrap();
        }
        assert_eq!(
            [q.drives[0].velocity_rad_s, q.drives[1].velocity_rad_s],
            [1.5, -2.0]
        );
    }

    /// Under torque, the work done is the energy gained; with friction it is less by exactly
    /// the friction's work (checked to the integration's accuracy).
    #[test]
    fn work_done_is_energy_gained_plus_friction_losses() {
        for cfg in [PlantConfig::ideal(), PlantConfig::paper()] {
            let mut p = swinging(&cfg, [0.0, 0.0]);
            let e0 = energy(&p);
            let (mut work, mut loss) = (0.0, 0.0);
            let n = 200;
            for k in 0..n {
                let tau = [
                    0.6 * (k as f64 * 0.05).sin(),
                    -0.4 * (k as f64 * 0.07).cos(),
                ];
                for _ in 0..10 {
                    let w0 = [p.drives[0].velocity_rad_s, p.drives[1].velocity_rad_s];
                    p.advance(tau, 5e-5, 1).unwrap();
                    let w1 = [p.drives[0].velocity_rad_s, p.drives[1].velocity_rad_s];
                    for j in 0..2 {
                        let w = 0.5 * (w0[j] + w1[j]);
                        let (b, c) = p.drives[j].friction();
                        work += tau[j] * w * 5e-5;
                        loss += (b * w * w + c * w.abs()) * 5e-5;
                    }
                }
            }
            let gained = energy(&p) - e0;
            eprintln!(
                "{}: work {work:.6e} J, friction {loss:.6e} J, energy gained {gained:.6e} J",
                cfg.description
            );
            assert!(gained > 1e-3, "{gained}");
            assert!(
                (work - loss - gained).abs() < 2e-3 * work.abs(),
                "work {work} loss {loss} gained {gained}"
            );
        }
    }

    /// Coulomb friction holds an axis that the torque cannot break away, even while the other
    /// axis accelerates and pulls on it through the linkage.
    #[test]
    fn an_axis_below_breakaway_stays_put() {
        let mut cfg = PlantConfig::ideal();
        cfg.drive_1.coulomb_friction_nm = 0.5;
        cfg.drive_2.coulomb_friction_nm = 0.5;
        let mut p = swinging(&cfg, [0.0, 0.0]);
        let start = p.drives[0].motor_rad;
        for _ in 0..100 {
            p.advance([0.1, 0.8], 5e-4, 10).unwrap();
        }
        assert_eq!(p.drives[0].motor_rad, start, "held by friction");
        assert!(
            p.drives[1].velocity_rad_s > 1.0,
            "the other axis moved: {}",
            p.drives[1].velocity_rad_s
        );
    }
}
