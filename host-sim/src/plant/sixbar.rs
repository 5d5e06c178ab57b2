//! The overconstrained six-bar of the paper's Fig. 1b, solved for static equilibrium.
//!
//! # Geometry
//! ```text
//!                         A0*  F1 (follower, length a)    A*
//!                           o ─────────────────────────── o ╮
//!                           ·                             · │ elbow piece K1
//!   ground  A0 = (0, w/2)   o ════ P1 (lever a, motor 1) ═ o A ─────── o A**
//!                                                           ╲  Q1 (b)  ╲  G1 (b)
//!                                                            ╲          ╲
//!                                   platform T:        D  o ──────────── o D**
//!                                                         │
//!                                            tool point C ●   (D = C + (0, w/2))
//!                                                         │
//!                                                      E  o ──────────── o E**
//!                                    (arm 2: the mirror image, B0 = (0, -w/2), P2, F2, K2, Q2, G2)
//! ```
//! Each arm has two parallelograms in series (drafting-machine style): A0-A-A*-A0* (lever P1 and
//! follower F1, offset `g`) keeps the elbow piece K1 at a constant orientation, A-D-D**-A**
//! (distal bar Q1 and follower G1, offset `h`) keeps the platform at K1's orientation. One arm's
//! pair would fix the platform's orientation; the second arm's pair fixes it again: the
//! mechanism is statically indeterminate by one. With D = C + (0, w/2) and A0 = (0, w/2),
//! `C = a·u(θ1) + b·u(θ3)`: the tool point moves exactly like the end point of the five-bar with
//! A0' = B0' = origin (`FiveBar::paper_nominal`), which the tests check to 0.01 µm.
//!
//! Offsets: `g1` points at 135° and `h1` at 45° (30 mm), perpendicular to the middle of the
//! ranges of the lever (9°..78°) and the distal bar (-78°..-9°) over the workspace, so neither
//! parallelogram comes closer than 35° to its flat (singular) shape. Arm 2 mirrors them in x.
//!
//! # Equilibrium
//! Unknowns: the planar poses `(x, y, φ)` of K1, K2 and T (9 numbers). The levers P1, P2 are set
//! by the link angles (the drives hold them). Elastic energy, as a sum of squared residuals:
//! * the six two-force bars F1, Q1, G1, F2, Q2, G2: `√k·(|P - Q| - L)`, `k = E·A/L`
//!   (aluminium, E = 70 GPa; Q bars 120 mm², followers 40 mm²: k ≈ 56 and 19 kN/mm), with the
//!   axial play of their two end pins as a smooth dead zone `s - c·tanh(s/c)`;
//! * the elbow bearings A (P1 tip to K1) and B: radial spring (20 kN/mm) with radial clearance,
//!   vector dead zone `r·(1 - c·tanh(|r|/c)/|r|)`, smooth at 0;
//! * inside a clearance a centring spring of `ratio·k` keeps the minimum unique.
//!
//! Manufacturing errors (every bar length, every pin on every body, the ground pivots) make the
//! parallelograms disagree; the redundant loop then carries internal forces that change with the
//! configuration, and so does the tool point's deviation: a configuration-dependent link-length
//! change the hidden five-bar cannot represent. Two parts, measured by the tests on the `paper`
//! plant over the workspace: the kinematic one (a parallelogram whose opposite sides differ by
//! δ turns its coupler by ~δ/offset, so the elbow pieces and the platform rotate with the
//! configuration): 100-170 µm of spread against the equivalent five-bar; and the elastic one
//! (bars and bearings deformed by the 370-640 N of internal force): ~1.7 µm. Axially loaded
//! aluminium bars are stiff; links that bend would make the elastic part larger (lower
//! `main_bar_section_mm2`, `follower_bar_section_mm2` or `pin_stiffness_n_per_mm` to model that).
//!
//! The layout as built (pins, bars, the equivalent five-bar) and the dead-zone springs are
//! `kinematics_core::sixbar`'s, which the firmware's benchmark port of this solve shares.
//!
//! Solver: Levenberg-Marquardt (Gauss-Newton with Marquardt damping only when a step fails) on
//! the 9 unknowns with the analytic Jacobian, 9x9 Cholesky. Warm start: the nominal closed-form
//! pose for the new angles plus the previous solution's deviation from its nominal pose; from
//! there 2-4 iterations reach a step below 1e-9 mm (the stopping rule; the last iteration only
//! confirms), i.e. the solution error is far below a nanometre. Cost (`cargo bench -p host-sim`,
//! release, shared 2-core host, so ±30 % from run to run): ~1.4 µs per iteration, 4-5 µs per
//! warm-started solve along a 2 kHz path (3.1 iterations), 5.5-7 µs between scattered grid
//! points (4.3 iterations), i.e. 150-175x the closed-form five-bar FK (24-35 ns) and 85-100x
//! its IK (40-60 ns).

use super::{deg, PlantError};
use crate::plant::config::{PlantModel, SixBarConfig};
use kinematics_core::sixbar::{damping_after, dead_zone_energy, limit_step, BarEnd, SixBarLayout};
use kinematics_core::{FiveBar, KinematicsError};
use nalgebra::{SMatrix, SVector};

type Mat9 = SMatrix<f64, 9, 9>;
type Vec9 = SVector<f64, 9>;

/// The result of one equilibrium solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SixBarSolution {
    /// Tool point C (machine frame).
    pub tool_mm: [f64; 2],
    /// Platform rotation from its nominal orientation.
    pub platform_rot_rad: f64,
    /// Tension in F1, Q1, G1, F2, Q2, G2 (N, positive = pulled).
    pub bar_tension_n: [f64; 6],
    /// Force carried by the elbow bearings A and B (N).
    pub pin_force_n: [f64; 2],
    /// LM iterations used.
    pub iterations: u32,
}

impl SixBarSolution {
    /// The largest |bar tension| (N).
    pub fn max_abs_tension_n(&self) -> f64 {
        self.bar_tension_n.iter().fold(0.0, |m, t| m.max(t.abs()))
    }
}

/// The six-bar with its (possibly erroneous) geometry, and the warm-start state.
#[derive(Clone, Debug)]
pub struct SixBar {
    model: PlantModel,
    /// Pins, bars and the equivalent five-bar (the warm start of the six-bar and the whole
    /// `fivebar` plant).
    layout: SixBarLayout<f64>,
    pin_k_n_per_mm: f64,
    pin_clearance_mm: f64,
    bar_clearance_mm: f64,
    centring_ratio: f64,
    /// Previous solution minus its nominal pose.
    deviation: Option<Vec9>,
}

fn sub(u: [f64; 2], v: [f64; 2]) -> [f64; 2] {
    [u[0] - v[0], u[1] - v[1]]
}

/// The refusal of link angles that do not assemble the equivalent five-bar.
fn not_assemblable(link_rad: [f64; 2], e: KinematicsError) -> PlantError {
    PlantError::NotAssemblable {
        link_deg: deg(link_rad),
        reason: e.to_string(),
    }
}

/// Accumulates the energy, its gradient and a (positive semi-definite) Hessian approximation:
/// exact for the springs and dead zones along their own directions, without the bars'
/// geometric stiffness (tension / length, 10⁻⁴ of the axial stiffness here), so Newton's
/// convergence stays linear with a rate of about 10⁻⁴ per iteration.
struct Normal {
    h: Mat9,
    g: Vec9,
    energy: f64,
}

impl Normal {
    /// A scalar coordinate `s` with gradient `grad` carrying energy `e` (derivatives `d1`, `d2`).
    fn add(&mut self, (e, d1, d2): (f64, f64, f64), grad: &Vec9) {
        self.h += grad * grad.transpose() * d2.max(0.0);
        self.g += grad * d1;
        self.energy += e;
    }
}

impl SixBar {
    pub fn new(cfg: &SixBarConfig) -> Self {
        SixBar {
            model: cfg.model,
            layout: SixBarLayout::new(&cfg.design(), &cfg.errors),
            pin_k_n_per_mm: cfg.pin_stiffness_n_per_mm,
            pin_clearance_mm: cfg.pin_clearance_mm,
            bar_clearance_mm: cfg.bar_end_clearance_mm / 2.0,
            centring_ratio: cfg.clearance_centring_ratio,
            deviation: None,
        }
    }

    /// The equivalent five-bar of the errored arms (link angles as its encoder angles, A0' at
    /// the origin of its frame): what the linkage's dynamics move on.
    pub fn equivalent_five_bar(&self) -> FiveBar<f64> {
        self.layout.five
    }

    /// Tool point of the equivalent five-bar (no stress): the `fivebar` plant.
    pub fn five_bar_tool_mm(&self, link_rad: [f64; 2]) -> Result<[f64; 2], PlantError> {
        self.layout
            .five_bar_tool_mm(link_rad)
            .map_err(|e| not_assemblable(link_rad, e))
    }

    /// The rigid-body pose the closed-form five-bar gives (unknown vector layout: K1, K2, T).
    fn nominal_pose(&self, link_rad: [f64; 2]) -> Result<Vec9, PlantError> {
        let pose = self
            .layout
            .nominal_pose(link_rad)
            .map_err(|e| not_assemblable(link_rad, e))?;
        Ok(Vec9::from_column_slice(&pose))
    }

    /// World position of a bar end and, for a body, its derivative by the body's angle.
    fn end(x: &Vec9, end: BarEnd<f64>) -> ([f64; 2], Option<(usize, [f64; 2])>) {
        match end {
            BarEnd::Ground(p) => (p, None),
            BarEnd::Body(b, r) => {
                let (s, c) = x[3 * b + 2].sin_cos();
                let rr = [c * r[0] - s * r[1], s * r[0] + c * r[1]];
                (
                    [x[3 * b] + rr[0], x[3 * b + 1] + rr[1]],
                    Some((b, [-rr[1], rr[0]])),
                )
            }
        }
    }

    /// The converged state `x` as a solution: its bar tensions and pin force assembled once more.
    fn solution(&self, x: &Vec9, tips: &[[f64; 2]; 2], iterations: u32) -> SixBarSolution {
        let mut tension = [0.0; 6];
        let mut pin = [0.0; 2];
        self.assemble(x, tips, Some((&mut tension, &mut pin)));
        SixBarSolution {
            tool_mm: [x[6], x[7]],
            platform_rot_rad: x[8],
            bar_tension_n: tension,
            pin_force_n: pin,
            iterations,
        }
    }

    /// Normal equations of the energy at `x`; with `forces`, also the bar tensions and pin forces.
    fn assemble(
        &self,
        x: &Vec9,
        tips: &[[f64; 2]; 2],
        forces: Option<(&mut [f64; 6], &mut [f64; 2])>,
    ) -> Normal {
        let mut n = Normal {
            h: Mat9::zeros(),
            g: Vec9::zeros(),
            energy: 0.0,
        };
        let mut tension = [0.0; 6];
        let mut pin = [0.0; 2];
        let cb = self.bar_clearance_mm;
        for (k, bar) in self.layout.bars.iter().enumerate() {
            let (p, dp) = Self::end(x, bar.p);
            let (q, dq) = Self::end(x, bar.q);
            let d = sub(q, p);
            let len = (d[0] * d[0] + d[1] * d[1]).sqrt();
            let u = [d[0] / len, d[1] / len];
            let s = len - bar.length_mm;
            // Gradient of the stretch s.
            let mut grad = Vec9::zeros();
            if let Some((b, t)) = dq {
                grad[3 * b] += u[0];
                grad[3 * b + 1] += u[1];
                grad[3 * b + 2] += u[0] * t[0] + u[1] * t[1];
            }
            if let Some((b, t)) = dp {
                grad[3 * b] -= u[0];
                grad[3 * b + 1] -= u[1];
                grad[3 * b + 2] -= u[0] * t[0] + u[1] * t[1];
            }
            let (e, d1, d2) = dead_zone_energy(s, cb, bar.k_n_per_mm);
            n.add((e, d1, d2), &grad);
            tension[k] = d1;
            if cb > 0.0 {
                let kc = bar.k_n_per_mm * self.centring_ratio;
                n.add((0.5 * kc * s * s, kc * s, kc), &grad);
                tension[k] += kc * s;
            }
        }
        let c = self.pin_clearance_mm;
        for i in 0..2 {
            // r = K_i's pin A - lever tip (K_i's frame origin is its pin A): radial dead zone.
            let r = [x[3 * i] - tips[i][0], x[3 * i + 1] - tips[i][1]];
            let rho = (r[0] * r[0] + r[1] * r[1]).sqrt();
            let k = self.pin_k_n_per_mm;
            let (e, d1, d2) = dead_zone_energy(rho, c, k);
            n.energy += e;
            let mut f = 0.0;
            if c <= 0.0 {
                // Plain spring: E = ½k|r|².
                for (a, ra) in r.iter().enumerate() {
                    n.g[3 * i + a] += k * ra;
                    n.h[(3 * i + a, 3 * i + a)] += k;
                }
                f = k * rho;
            } else if rho > 1e-12 {
                let u = [r[0] / rho, r[1] / rho];
                for a in 0..2 {
                    n.g[3 * i + a] += d1 * u[a];
                    for b in 0..2 {
                        let kron = if a == b { 1.0 } else { 0.0 };
                        n.h[(3 * i + a, 3 * i + b)] +=
                            d2.max(0.0) * u[a] * u[b] + d1 / rho * (kron - u[a] * u[b]);
                    }
                }
                f = d1;
            }
            if c > 0.0 {
                let kc = k * self.centring_ratio;
                n.energy += 0.5 * kc * rho * rho;
                for (a, ra) in r.iter().enumerate() {
                    n.g[3 * i + a] += kc * ra;
                    n.h[(3 * i + a, 3 * i + a)] += kc;
                }
                f += kc * rho;
            }
            pin[i] = f;
        }
        if let Some((t, p)) = forces {
            *t = tension;
            *p = pin;
        }
        n
    }

    /// Static equilibrium for geometric link angles (rad), warm-started from the last call.
    /// With the `fivebar` model: the equivalent five-bar's FK, forces zero.
    pub fn solve(&mut self, link_rad: [f64; 2]) -> Result<SixBarSolution, PlantError> {
        if self.model == PlantModel::Fivebar {
            return Ok(SixBarSolution {
                tool_mm: self.five_bar_tool_mm(link_rad)?,
                platform_rot_rad: 0.0,
                bar_tension_n: [0.0; 6],
                pin_force_n: [0.0; 2],
                iterations: 0,
            });
        }
        let nominal = self.nominal_pose(link_rad)?;
        let guess = nominal + self.deviation.unwrap_or_else(Vec9::zeros);
        match self.solve_from(link_rad, guess) {
            Ok((sol, x)) => {
                self.deviation = Some(x - nominal);
                Ok(sol)
            }
            Err(e) => {
                // A bad warm start must not poison the next call: retry from the nominal pose.
                self.deviation = None;
                let (sol, x) = self.solve_from(link_rad, nominal).map_err(|_| e)?;
                self.deviation = Some(x - nominal);
                Ok(sol)
            }
        }
    }

    /// Levenberg-Marquardt from `guess`; returns the solution and the unknown vector.
    pub fn solve_from(
        &self,
        link_rad: [f64; 2],
        guess: Vec9,
    ) -> Result<(SixBarSolution, Vec9), PlantError> {
        const MAX_ITER: u32 = 60;
        const STEP_TOL_MM: f64 = 1e-9;
        let tips = self.layout.lever_tips(link_rad);
        let mut x = guess;
        let mut n = self.assemble(&x, &tips, None);
        let mut mu = 0.0f64;
        for iter in 1..=MAX_ITER {
            let mut h = n.h;
            for d in 0..9 {
                h[(d, d)] *= 1.0 + mu;
                h[(d, d)] += 1e-12;
            }
            let Some(chol) = h.cholesky() else {
                return Err(PlantError::SingularStiffness {
                    link_deg: deg(link_rad),
                });
            };
            let mut step = chol.solve(&(-n.g));
            let big = limit_step(step.as_mut_slice());
            let trial = x + step;
            let nt = self.assemble(&trial, &tips, None);
            let accepted = nt.energy <= n.energy * (1.0 + 1e-12) + 1e-18;
            mu = damping_after(mu, accepted);
            if accepted {
                x = trial;
                n = nt;
                if big < STEP_TOL_MM {
                    return Ok((self.solution(&x, &tips, iter), x));
                }
            } else if big < STEP_TOL_MM && mu > 1e6 {
                // No descent left at round-off level: we are at the minimum.
                return Ok((self.solution(&x, &tips, iter), x));
            }
        }
        Err(PlantError::NotConverged {
            link_deg: deg(link_rad),
            iterations: MAX_ITER,
        })
    }

    /// The nominal (rigid, closed-form) unknown vector, for tests that perturb it.
    pub fn nominal_unknowns(&self, link_rad: [f64; 2]) -> Result<Vec9, PlantError> {
        self.nominal_pose(link_rad)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::config::PlantConfig;

    /// 11 × 11 targets over the paper machine's workspace.
    fn grid_targets() -> Vec<[f64; 2]> {
        let ws = crate::machine_spec::MachineSpec::paper().workspace;
        let mut v = Vec::new();
        for i in 0..=10 {
            for j in 0..=10 {
                v.push([ws.x_mm[0] + 10.0 * i as f64, ws.y_mm[0] + 15.0 * j as f64]);
            }
        }
        v
    }

    #[test]
    fn ideal_sixbar_equals_fivebar_fk() {
        let five = FiveBar::<f64>::paper_nominal();
        let mut sb = SixBar::new(&PlantConfig::ideal().sixbar);
        let mut worst: f64 = 0.0;
        for (k, t) in grid_targets().into_iter().enumerate() {
            let theta = five.inverse(t, 0.0).unwrap();
            let c = five.forward(theta, 0.0).unwrap();
            // Start far from the answer (0.5 mm, 5 mrad) so the solver, not the guess, decides.
            let mut guess = sb.nominal_unknowns(theta).unwrap();
            for d in 0..9 {
                guess[d] +=
                    if d % 3 == 2 { 5e-3 } else { 0.5 } * if (d + k) % 2 == 0 { 1.0 } else { -1.0 };
            }
            let (sol, _) = sb.solve_from(theta, guess).unwrap();
            worst = worst
                .max(((sol.tool_mm[0] - c[0]).powi(2) + (sol.tool_mm[1] - c[1]).powi(2)).sqrt());
            assert!(sol.max_abs_tension_n() < 1e-6, "{sol:?}");
            let warm = sb.solve(theta).unwrap();
            worst = worst
                .max(((warm.tool_mm[0] - c[0]).powi(2) + (warm.tool_mm[1] - c[1]).powi(2)).sqrt());
        }
        assert!(worst < 1e-5, "worst deviation {} µm", worst * 1e3);
    }

    #[test]
    fn errors_create_configuration_dependent_stress() {
        let cfg = PlantConfig::ideal().with_random_errors(3, 0.05, 0.0);
        let five = FiveBar::<f64>::paper_nominal();
        let mut sb = SixBar::new(&cfg.sixbar);
        let mut tensions = Vec::new();
        for t in grid_targets() {
            let theta = five.inverse(t, 0.0).unwrap();
            let sol = sb.solve(theta).unwrap();
            assert!(sol.iterations <= 20, "{sol:?}");
            // Cold start lands on the same equilibrium.
            let (cold, _) = sb
                .solve_from(theta, sb.nominal_unknowns(theta).unwrap())
                .unwrap();
            assert!(
                (cold.tool_mm[0] - sol.tool_mm[0]).abs() < 1e-7
                    && (cold.tool_mm[1] - sol.tool_mm[1]).abs() < 1e-7
            );
            tensions.push(sol.bar_tension_n[1]);
        }
        let lo = tensions.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = tensions.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        assert!(
            hi.abs().max(lo.abs()) > 10.0,
            "stress too small: {lo}..{hi} N"
        );
        assert!(
            hi - lo > 0.2 * hi.abs().max(lo.abs()),
            "stress does not vary: {lo}..{hi} N"
        );
    }

    #[test]
    fn clearance_plant_converges() {
        let mut cfg = PlantConfig::paper();
        cfg.sixbar.pin_clearance_mm = 0.01;
        cfg.sixbar.bar_end_clearance_mm = 0.01;
        let five = FiveBar::<f64>::paper_nominal();
        let mut sb = SixBar::new(&cfg.sixbar);
        for t in grid_targets() {
            let theta = five.inverse(t, 0.0).unwrap();
            let sol = sb.solve(theta).unwrap();
            assert!(sol.iterations <= 40, "{sol:?}");
        }
    }

    #[test]
    fn solver_converges_on_random_plants() {
        let five = FiveBar::<f64>::paper_nominal();
        for seed in 0..6 {
            let mut cfg = PlantConfig::ideal().with_random_errors(seed, 0.2, 0.0);
            cfg.sixbar.pin_clearance_mm = 0.005;
            cfg.sixbar.bar_end_clearance_mm = 0.004;
            let mut sb = SixBar::new(&cfg.sixbar);
            for t in grid_targets() {
                let theta = five.inverse(t, 0.0).unwrap();
                let sol = sb.solve(theta).unwrap();
                assert!(sol.iterations <= 30, "seed {seed}: {sol:?}");
            }
        }
    }

    #[test]
    fn paper_sixbar_departs_from_its_equivalent_fivebar() {
        // What no five-bar can represent: the stress-induced, configuration-dependent part.
        let cfg = PlantConfig::paper();
        let five = FiveBar::<f64>::paper_nominal();
        let mut sb = SixBar::new(&cfg.sixbar);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for t in grid_targets() {
            let theta = five.inverse(t, 0.0).unwrap();
            let s = sb.solve(theta).unwrap().tool_mm;
            let f = sb.five_bar_tool_mm(theta).unwrap();
            for k in 0..2 {
                lo[k] = lo[k].min(s[k] - f[k]);
                hi[k] = hi[k].max(s[k] - f[k]);
            }
        }
        let spread_um = [(hi[0] - lo[0]) * 1e3, (hi[1] - lo[1]) * 1e3];
        eprintln!(
            "six-bar minus equivalent five-bar: spread x {:.1} um, y {:.1} um",
            spread_um[0], spread_um[1]
        );
        assert!(spread_um[0].max(spread_um[1]) > 2.0, "{spread_um:?}");
    }

    #[test]
    fn stress_moves_the_tool_by_a_configuration_dependent_amount() {
        // The elastic part alone: the paper plant against the same geometry made 10⁴ times
        // stiffer without clearances (a rigid best-fit assembly).
        let cfg = PlantConfig::paper();
        let mut stiff = cfg.clone();
        stiff.sixbar.youngs_modulus_n_per_mm2 *= 1e4;
        stiff.sixbar.pin_stiffness_n_per_mm *= 1e4;
        stiff.sixbar.pin_clearance_mm = 0.0;
        stiff.sixbar.bar_end_clearance_mm = 0.0;
        let five = FiveBar::<f64>::paper_nominal();
        let (mut soft, mut rigid) = (SixBar::new(&cfg.sixbar), SixBar::new(&stiff.sixbar));
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for t in grid_targets() {
            let theta = five.inverse(t, 0.0).unwrap();
            let (s, r) = (soft.solve(theta).unwrap(), rigid.solve(theta).unwrap());
            for k in 0..2 {
                lo[k] = lo[k].min(s.tool_mm[k] - r.tool_mm[k]);
                hi[k] = hi[k].max(s.tool_mm[k] - r.tool_mm[k]);
            }
        }
        let spread_um = (hi[0] - lo[0]).max(hi[1] - lo[1]) * 1e3;
        eprintln!("elastic part of the tool position: spread {spread_um:.2} um");
        // About 1.7 µm with the paper plant's aluminium bars and 20 kN/mm bearings.
        assert!(spread_um > 0.5 && spread_um < 20.0, "{spread_um}");
    }
}
