//! The six-bar's static equilibrium as the plant solves it, ported to `no_std` f32 for the
//! benchmark only: what a numerical solve of the real mechanism would cost on the MCU, the
//! paper's reason for controlling through the hidden robot. Not part of any firmware.
//!
//! The mechanism is host-sim's plant (`host-sim/src/plant/sixbar.rs`, which documents it):
//! its layout as built (pins, bars, the equivalent five-bar that gives the warm start) and its
//! dead-zone springs are `kinematics_core::sixbar`, shared with the plant. The solver is the
//! plant's too: 9 unknowns (the planar poses of the elbow pieces K1, K2 and the platform T),
//! the elastic energy of six two-force bars and two elbow bearings,
//! Levenberg-Marquardt with the analytic gradient and Gauss-Newton Hessian, a 9x9 Cholesky per
//! iteration, warm-started from the closed-form five-bar pose plus the previous solution's
//! deviation. `tests/tests/sixbar_port.rs` checks that it lands on host-sim's tool point.
//!
//! Why the solve itself is a second copy: host-sim's runs in f64 on nalgebra's matrices (std)
//! and also assembles the bar forces; an MCU implementation differs in what makes it fair:
//! * f32 instead of f64: the Cortex-M4F has a single-precision FPU and f64 would run in
//!   software (tens of times slower), so f32 is the fair, favourable case for the numerical
//!   solve. Its coordinates are then resolved to ~1e-5 mm, so the stopping rule is a step
//!   below 2e-5 mm (host-sim: 1e-9 mm), and the step test accepts an energy rise within the
//!   energy's own round-off (each spring's force times the resolution of its length: a
//!   stretch is the difference of two ~150 mm lengths), else near the minimum every step
//!   would be refused on noise.
//! * The sine and cosine of each body's angle once per assembly (host-sim: per bar end), the
//!   Hessian's outer products on the non-zero entries of each gradient only, a bar's
//!   centring spring folded into the same outer product: what an MCU implementation would do.
//! * Only the tool point is returned (host-sim also assembles the bar forces once more).
//!
//! All three make the figure a lower bound of what the plant's solve costs.

// Index loops read like the linear algebra they implement (9x9 matrices, 3 dofs per body).
#![allow(clippy::needless_range_loop)]
// `!(x > 0)` instead of `x <= 0` is deliberate: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use kinematics_core::sixbar::{
    damping_after, dead_zone_energy, limit_step, BarEnd, SixBarDesign, SixBarErrors, SixBarLayout,
};
use kinematics_core::{FiveBar, Real};

/// The linkage, as host-sim's `SixBarConfig` (without its plant-model switch): the design and
/// errors the layout is built from, and the bearings' and clearances' springs.
#[derive(Clone, Debug)]
pub struct SixBarParams {
    pub design: SixBarDesign<f32>,
    pub errors: SixBarErrors<f32>,
    pub pin_stiffness_n_per_mm: f32,
    pub pin_clearance_mm: f32,
    pub bar_end_clearance_mm: f32,
    pub clearance_centring_ratio: f32,
}

impl SixBarParams {
    /// host-sim's `paper` plant (`host-sim/plants/paper.toml`; the port's test checks that
    /// these numbers are still that plant's).
    pub fn paper() -> Self {
        let r = 30.0 * core::f32::consts::FRAC_1_SQRT_2;
        let mirror = |v: [f32; 2]| [v[0], -v[1]];
        let (g, h) = ([-r, r], [r, r]);
        SixBarParams {
            design: SixBarDesign {
                nominal: FiveBar::paper_nominal(),
                platform_half_width_mm: 20.0,
                parallelogram_offsets_mm: [[g, h], [mirror(g), mirror(h)]],
                youngs_modulus_n_per_mm2: 70_000.0,
                main_bar_section_mm2: 120.0,
                follower_bar_section_mm2: 40.0,
            },
            errors: SixBarErrors {
                lever_length_mm: [-1.58, 1.52],
                bar_f_length_mm: [-1.55, 1.58],
                bar_q_length_mm: [2.26, -2.34],
                bar_g_length_mm: [2.31, -2.30],
                ground_motor_1_mm: [0.02, -0.01],
                ground_motor_2_mm: [-0.01, 0.015],
                ground_follower_1_mm: [0.04, -0.03],
                ground_follower_2_mm: [-0.02, 0.05],
                elbow_1_pin_q_mm: [0.01, 0.02],
                elbow_1_pin_f_mm: [-0.05, 0.03],
                elbow_1_pin_g_mm: [0.04, 0.06],
                elbow_2_pin_q_mm: [-0.02, 0.01],
                elbow_2_pin_f_mm: [0.03, -0.04],
                elbow_2_pin_g_mm: [-0.06, 0.02],
                platform_pin_d_mm: [0.015, -0.01],
                platform_pin_dd_mm: [-0.03, 0.05],
                platform_pin_e_mm: [0.01, 0.02],
                platform_pin_ee_mm: [0.05, -0.04],
            },
            pin_stiffness_n_per_mm: 20_000.0,
            pin_clearance_mm: 0.003,
            bar_end_clearance_mm: 0.002,
            clearance_centring_ratio: 1e-3,
        }
    }
}

/// Why a solve failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SolveError {
    /// The link angles do not assemble the equivalent five-bar (no warm start).
    NotAssemblable,
    /// The stiffness matrix lost positive definiteness.
    Singular,
    /// No convergence in the iteration limit.
    NoConvergence,
}

/// The tool point and the iterations it took.
#[derive(Clone, Copy, Debug)]
pub struct Solution {
    pub tool_mm: [f32; 2],
    pub iterations: u32,
}

type Vec9 = [f32; 9];
type Mat9 = [[f32; 9]; 9];

/// The six-bar and its warm-start state.
pub struct SixBar {
    layout: SixBarLayout<f32>,
    pin_k_n_per_mm: f32,
    pin_clearance_mm: f32,
    bar_clearance_mm: f32,
    centring_ratio: f32,
    deviation: Option<Vec9>,
}

fn sub(u: [f32; 2], v: [f32; 2]) -> [f32; 2] {
    [u[0] - v[0], u[1] - v[1]]
}

/// Energy, gradient and Gauss-Newton Hessian at one point.
struct Normal {
    h: Mat9,
    g: Vec9,
    energy: f32,
    /// The energy's round-off: each spring's force times the f32 resolution of its length
    /// (a stretch is a difference of ~150 mm lengths, resolved to ~1e-5 mm).
    noise: f32,
}

impl Normal {
    /// A scalar coordinate with sparse gradient `(index, value)` carrying energy `e`,
    /// first derivative `d1` and (clamped) second derivative `d2`.
    fn add(&mut self, e: f32, d1: f32, d2: f32, grad: &[(usize, f32)]) {
        for &(i, gi) in grad {
            self.g[i] += gi * d1;
            for &(j, gj) in grad {
                self.h[i][j] += gi * gj * d2;
            }
        }
        self.energy += e;
    }
}

impl SixBar {
    /// The six-bar of `cfg`, laid out as host-sim's `SixBar::new` lays it out.
    pub fn new(cfg: &SixBarParams) -> Self {
        SixBar {
            layout: SixBarLayout::new(&cfg.design, &cfg.errors),
            pin_k_n_per_mm: cfg.pin_stiffness_n_per_mm,
            pin_clearance_mm: cfg.pin_clearance_mm,
            bar_clearance_mm: cfg.bar_end_clearance_mm / 2.0,
            centring_ratio: cfg.clearance_centring_ratio,
            deviation: None,
        }
    }

    /// The rigid pose the closed-form equivalent five-bar gives (K1, K2, T).
    fn nominal_pose(&self, link_rad: [f32; 2]) -> Result<Vec9, SolveError> {
        self.layout
            .nominal_pose(link_rad)
            .map_err(|_| SolveError::NotAssemblable)
    }

    /// Normal equations of the energy at `x`.
    fn assemble(&self, x: &Vec9, tips: &[[f32; 2]; 2]) -> Normal {
        let mut n = Normal {
            h: [[0.0; 9]; 9],
            g: [0.0; 9],
            energy: 0.0,
            noise: 0.0,
        };
        // `Real::` explicitly: on the host, std's inherent `f32` methods would shadow the core's.
        let rot = [
            Real::sin_cos(x[2]),
            Real::sin_cos(x[5]),
            Real::sin_cos(x[8]),
        ];
        // World position of a bar end and, on a body, its derivative by the body's angle.
        let end = |e: BarEnd<f32>| -> ([f32; 2], Option<(usize, [f32; 2])>) {
            match e {
                BarEnd::Ground(p) => (p, None),
                BarEnd::Body(b, r) => {
                    let (s, c) = rot[b];
                    let rr = [c * r[0] - s * r[1], s * r[0] + c * r[1]];
                    (
                        [x[3 * b] + rr[0], x[3 * b + 1] + rr[1]],
                        Some((b, [-rr[1], rr[0]])),
                    )
                }
            }
        };
        let cb = self.bar_clearance_mm;
        for bar in &self.layout.bars {
            let (p, dp) = end(bar.p);
            let (q, dq) = end(bar.q);
            let d = sub(q, p);
            let len = Real::sqrt(d[0] * d[0] + d[1] * d[1]);
            let inv = 1.0 / len;
            let u = [d[0] * inv, d[1] * inv];
            let s = len - bar.length_mm;
            let mut grad = [(0usize, 0.0f32); 6];
            let mut count = 0;
            for (side, sign) in [(dq, 1.0f32), (dp, -1.0)] {
                if let Some((b, t)) = side {
                    grad[count] = (3 * b, sign * u[0]);
                    grad[count + 1] = (3 * b + 1, sign * u[1]);
                    grad[count + 2] = (3 * b + 2, sign * (u[0] * t[0] + u[1] * t[1]));
                    count += 3;
                }
            }
            let (mut e, mut d1, d2) = dead_zone_energy(s, cb, bar.k_n_per_mm);
            let mut d2 = Real::max(d2, 0.0);
            if cb > 0.0 {
                let kc = bar.k_n_per_mm * self.centring_ratio;
                e += 0.5 * kc * s * s;
                d1 += kc * s;
                d2 += kc;
            }
            n.add(e, d1, d2, &grad[..count]);
            n.noise += Real::abs(d1) * len * 4.0 * f32::EPSILON;
        }
        let c = self.pin_clearance_mm;
        let k = self.pin_k_n_per_mm;
        for i in 0..2 {
            let r = [x[3 * i] - tips[i][0], x[3 * i + 1] - tips[i][1]];
            let rho = Real::sqrt(r[0] * r[0] + r[1] * r[1]);
            let (e, d1, d2) = dead_zone_energy(rho, c, k);
            n.energy += e;
            // The pin's offset is a difference of ~200 mm positions.
            n.noise += (Real::abs(d1) + k * self.centring_ratio * rho) * 800.0 * f32::EPSILON;
            if c <= 0.0 {
                for a in 0..2 {
                    n.g[3 * i + a] += k * r[a];
                    n.h[3 * i + a][3 * i + a] += k;
                }
            } else if rho > 1e-12 {
                let u = [r[0] / rho, r[1] / rho];
                for a in 0..2 {
                    n.g[3 * i + a] += d1 * u[a];
                    for b in 0..2 {
                        let kron = if a == b { 1.0 } else { 0.0 };
                        n.h[3 * i + a][3 * i + b] +=
                            Real::max(d2, 0.0) * u[a] * u[b] + d1 / rho * (kron - u[a] * u[b]);
                    }
                }
            }
            if c > 0.0 {
                let kc = k * self.centring_ratio;
                n.energy += 0.5 * kc * rho * rho;
                for a in 0..2 {
                    n.g[3 * i + a] += kc * r[a];
                    n.h[3 * i + a][3 * i + a] += kc;
                }
            }
        }
        n
    }

    /// Static equilibrium for geometric link angles, warm-started from the last call.
    pub fn solve(&mut self, link_rad: [f32; 2]) -> Result<Solution, SolveError> {
        let nominal = self.nominal_pose(link_rad)?;
        let mut guess = nominal;
        if let Some(dev) = self.deviation {
            for k in 0..9 {
                guess[k] += dev[k];
            }
        }
        let (sol, x) = match self.solve_from(link_rad, guess) {
            Ok(r) => r,
            // A bad warm start must not poison the next call: retry from the nominal pose.
            Err(_) => self.solve_from(link_rad, nominal)?,
        };
        let mut dev = [0.0; 9];
        for k in 0..9 {
            dev[k] = x[k] - nominal[k];
        }
        self.deviation = Some(dev);
        Ok(sol)
    }

    /// Levenberg-Marquardt from `guess`: the solution and the unknown vector.
    pub fn solve_from(
        &self,
        link_rad: [f32; 2],
        guess: Vec9,
    ) -> Result<(Solution, Vec9), SolveError> {
        const MAX_ITER: u32 = 60;
        const STEP_TOL_MM: f32 = 2e-5;
        let tips = self.layout.lever_tips(link_rad);
        let mut x = guess;
        let mut n = self.assemble(&x, &tips);
        let mut mu = 0.0f32;
        for iter in 1..=MAX_ITER {
            let mut h = n.h;
            for (d, row) in h.iter_mut().enumerate() {
                row[d] *= 1.0 + mu;
            }
            let mut step = [0.0f32; 9];
            for k in 0..9 {
                step[k] = -n.g[k];
            }
            cholesky_solve(&mut h, &mut step)?;
            let big = limit_step(&mut step);
            let mut trial = x;
            for k in 0..9 {
                trial[k] += step[k];
            }
            let nt = self.assemble(&trial, &tips);
            let done = Ok((
                Solution {
                    tool_mm: [x[6], x[7]],
                    iterations: iter,
                },
                x,
            ));
            // A rise within the energy's round-off is no rise: near the minimum the f32 energy
            // cannot tell steps apart, and refusing them would stall the solve.
            let accepted = nt.energy <= n.energy + n.noise + nt.noise;
            mu = damping_after(mu, accepted);
            if accepted {
                x = trial;
                n = nt;
                if big < STEP_TOL_MM {
                    return Ok((
                        Solution {
                            tool_mm: [x[6], x[7]],
                            iterations: iter,
                        },
                        x,
                    ));
                }
            } else if big < STEP_TOL_MM && mu > 1e6 {
                // No descent left at round-off level: we are at the minimum.
                return done;
            }
        }
        Err(SolveError::NoConvergence)
    }
}

/// Solves `h·x = b` in place (`b` becomes `x`) by Cholesky, `h` overwritten by its factor.
fn cholesky_solve(h: &mut Mat9, b: &mut Vec9) -> Result<(), SolveError> {
    let mut inv_diag = [0.0f32; 9];
    for j in 0..9 {
        let mut d = h[j][j];
        for k in 0..j {
            d -= h[j][k] * h[j][k];
        }
        if !(d > 0.0) {
            return Err(SolveError::Singular);
        }
        let l = Real::sqrt(d);
        inv_diag[j] = 1.0 / l;
        for i in j + 1..9 {
            let mut v = h[i][j];
            for k in 0..j {
                v -= h[i][k] * h[j][k];
            }
            h[i][j] = v * inv_diag[j];
        }
    }
    for i in 0..9 {
        let mut v = b[i];
        for k in 0..i {
            v -= h[i][k] * b[k];
        }
        b[i] = v * inv_diag[i];
    }
    for i in (0..9).rev() {
        let mut v = b[i];
        for k in i + 1..9 {
            v -= h[k][i] * b[k];
        }
        b[i] = v * inv_diag[i];
    }
    Ok(())
}
