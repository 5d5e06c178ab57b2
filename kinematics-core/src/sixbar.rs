//! The overconstrained six-bar of the paper's Fig. 1b as built (every bar length and pin off
//! by its manufacturing error): where its pins and bars sit, its bars' springs, the
//! equivalent five-bar the tool point moves like, and the rigid pose that five-bar gives for
//! the link angles (the static solve's warm start).
//!
//! Why in the core: two programs solve this mechanism. host-sim's plant (f64, std) is the
//! simulated machine every tool is tested against, and the firmware's benchmark ports its solve
//! to the MCU (f32, no_std) to show what a numerical solve of the real mechanism would cost in
//! the 2 kHz step. Both lay the mechanism out from this one source, so the port cannot drift
//! from the plant. The solvers themselves stay apart: the plant's is the reference (f64,
//! bar forces, tight stopping rule), the port's is what an MCU would run (f32 round-off
//! tolerances, sparse products). host-sim's `plant::sixbar` documents the model.
//!
//! The two solves also share their step rules ([`limit_step`], [`damping_after`]).
//!
//! Cost: building the layout is a few dozen additions and one division per bar; the pose is
//! two `sin_cos` and one closed-form five-bar FK.

use crate::error::KinematicsError;
use crate::model::FiveBar;
use crate::real::Real;

/// Manufacturing errors of the six-bar (mm): each bar length, each pin position on each body.
/// Arm 1 / arm 2 pairs are `[arm1, arm2]`; pin errors are `[x, y]` in the body's frame
/// (machine frame at the nominal pose). Pins are named as in host-sim's `plant::sixbar`.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct SixBarErrors<T> {
    /// Driven levers P1, P2 (A0→A, B0→B): length errors.
    pub lever_length_mm: [T; 2],
    /// Followers F1, F2 of the first parallelograms: length errors.
    pub bar_f_length_mm: [T; 2],
    /// Distal bars Q1, Q2 (A→D, B→E): length errors.
    pub bar_q_length_mm: [T; 2],
    /// Followers G1, G2 of the second parallelograms: length errors.
    pub bar_g_length_mm: [T; 2],
    /// Motor axis A0 on the ground.
    pub ground_motor_1_mm: [T; 2],
    /// Motor axis B0 on the ground.
    pub ground_motor_2_mm: [T; 2],
    /// Follower ground pivot A0*.
    pub ground_follower_1_mm: [T; 2],
    /// Follower ground pivot B0*.
    pub ground_follower_2_mm: [T; 2],
    /// Elbow piece K1: pin of Q1 (nominally at A).
    pub elbow_1_pin_q_mm: [T; 2],
    /// Elbow piece K1: pin of F1 (A*).
    pub elbow_1_pin_f_mm: [T; 2],
    /// Elbow piece K1: pin of G1 (A**).
    pub elbow_1_pin_g_mm: [T; 2],
    /// Elbow piece K2: pin of Q2 (nominally at B).
    pub elbow_2_pin_q_mm: [T; 2],
    /// Elbow piece K2: pin of F2 (B*).
    pub elbow_2_pin_f_mm: [T; 2],
    /// Elbow piece K2: pin of G2 (B**).
    pub elbow_2_pin_g_mm: [T; 2],
    /// Platform T: pin D (arm 1), relative to the tool point C.
    pub platform_pin_d_mm: [T; 2],
    /// Platform T: pin D** (arm 1), relative to the tool point C.
    pub platform_pin_dd_mm: [T; 2],
    /// Platform T: pin E (arm 2), relative to the tool point C.
    pub platform_pin_e_mm: [T; 2],
    /// Platform T: pin E** (arm 2), relative to the tool point C.
    pub platform_pin_ee_mm: [T; 2],
}

impl<T: Copy> SixBarErrors<T> {
    /// Every error converted by `f` (e.g. to another float type).
    pub fn map<U>(&self, f: impl Fn(T) -> U) -> SixBarErrors<U> {
        let v = |a: [T; 2]| [f(a[0]), f(a[1])];
        SixBarErrors {
            lever_length_mm: v(self.lever_length_mm),
            bar_f_length_mm: v(self.bar_f_length_mm),
            bar_q_length_mm: v(self.bar_q_length_mm),
            bar_g_length_mm: v(self.bar_g_length_mm),
            ground_motor_1_mm: v(self.ground_motor_1_mm),
            ground_motor_2_mm: v(self.ground_motor_2_mm),
            ground_follower_1_mm: v(self.ground_follower_1_mm),
            ground_follower_2_mm: v(self.ground_follower_2_mm),
            elbow_1_pin_q_mm: v(self.elbow_1_pin_q_mm),
            elbow_1_pin_f_mm: v(self.elbow_1_pin_f_mm),
            elbow_1_pin_g_mm: v(self.elbow_1_pin_g_mm),
            elbow_2_pin_q_mm: v(self.elbow_2_pin_q_mm),
            elbow_2_pin_f_mm: v(self.elbow_2_pin_f_mm),
            elbow_2_pin_g_mm: v(self.elbow_2_pin_g_mm),
            platform_pin_d_mm: v(self.platform_pin_d_mm),
            platform_pin_dd_mm: v(self.platform_pin_dd_mm),
            platform_pin_e_mm: v(self.platform_pin_e_mm),
            platform_pin_ee_mm: v(self.platform_pin_ee_mm),
        }
    }

    /// Every pin position error (`[x, y]` each), in declaration order: one list for whoever
    /// draws or scales them, so that a pin added to the struct is not forgotten there.
    pub fn pins_mut(&mut self) -> [&mut [T; 2]; 14] {
        [
            &mut self.ground_motor_1_mm,
            &mut self.ground_motor_2_mm,
            &mut self.ground_follower_1_mm,
            &mut self.ground_follower_2_mm,
            &mut self.elbow_1_pin_q_mm,
            &mut self.elbow_1_pin_f_mm,
            &mut self.elbow_1_pin_g_mm,
            &mut self.elbow_2_pin_q_mm,
            &mut self.elbow_2_pin_f_mm,
            &mut self.elbow_2_pin_g_mm,
            &mut self.platform_pin_d_mm,
            &mut self.platform_pin_dd_mm,
            &mut self.platform_pin_e_mm,
            &mut self.platform_pin_ee_mm,
        ]
    }
}

/// What the layout is built from besides the errors.
#[derive(Clone, Copy, Debug)]
pub struct SixBarDesign<T> {
    /// The nominal five-bar the six-bar is built around (its lengths, bases, working mode).
    pub nominal: FiveBar<T>,
    /// Half the platform's DE distance (D = C + (0, w/2), E = C - (0, w/2)).
    pub platform_half_width_mm: T,
    /// The two parallelogram offsets of each arm: `[[g1, h1], [g2, h2]]`.
    pub parallelogram_offsets_mm: [[[T; 2]; 2]; 2],
    /// Young's modulus of the bars (N/mm²).
    pub youngs_modulus_n_per_mm2: T,
    /// Cross-section of the distal bars Q1, Q2 (mm²).
    pub main_bar_section_mm2: T,
    /// Cross-section of the followers F and G (mm²).
    pub follower_bar_section_mm2: T,
}

/// Where a bar end is: on the ground (a fixed point) or on body 0 (K1), 1 (K2), 2 (T), in
/// that body's frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BarEnd<T> {
    /// A ground pivot (machine frame, mm).
    Ground([T; 2]),
    /// A pin on body `0..3`, in the body's frame (mm).
    Body(usize, [T; 2]),
}

/// A two-force bar: its ends, its length and its axial stiffness `k = E·A/L`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bar<T> {
    /// One end.
    pub p: BarEnd<T>,
    /// The other end.
    pub q: BarEnd<T>,
    /// Unstressed length (mm).
    pub length_mm: T,
    /// Axial stiffness (N/mm).
    pub k_n_per_mm: T,
}

/// The six-bar as built: the motors and levers, the six bars F1, Q1, G1, F2, Q2, G2, and the
/// equivalent five-bar of the errored arms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SixBarLayout<T> {
    /// The motors' axes A0, B0 (machine frame).
    pub motor_mm: [[T; 2]; 2],
    /// The levers P1, P2 as built.
    pub lever_mm: [T; 2],
    /// F1, Q1, G1 (arm 1), F2, Q2, G2 (arm 2).
    pub bars: [Bar<T>; 6],
    /// The equivalent five-bar of the errored arms (link angles as its encoder angles, A0' at
    /// the origin of its frame).
    pub five: FiveBar<T>,
    /// Where the equivalent five-bar's frame sits (machine frame, mm).
    pub five_base_mm: [T; 2],
}

fn add<T: Real>(u: [T; 2], v: [T; 2]) -> [T; 2] {
    [u[0] + v[0], u[1] + v[1]]
}

fn sub<T: Real>(u: [T; 2], v: [T; 2]) -> [T; 2] {
    [u[0] - v[0], u[1] - v[1]]
}

impl<T: Real> SixBarLayout<T> {
    /// The mechanism `design` built with `errors`.
    pub fn new(design: &SixBarDesign<T>, errors: &SixBarErrors<T>) -> Self {
        let e = errors;
        let nominal = design.nominal;
        let w2 = design.platform_half_width_mm;
        let [[g1, h1], [g2, h2]] = design.parallelogram_offsets_mm;
        let (g, h) = ([g1, g2], [h1, h2]);
        // The motors' axes: w/2 above A0 and below B0 (D and E sit so on the platform).
        let a0 = nominal.base_a0_mm;
        let b0 = add(a0, nominal.base_b0_mm);
        let axis = [add(a0, [T::ZERO, w2]), add(b0, [T::ZERO, -w2])];
        let motor = [
            add(axis[0], e.ground_motor_1_mm),
            add(axis[1], e.ground_motor_2_mm),
        ];
        let follower = [
            add(add(axis[0], g[0]), e.ground_follower_1_mm),
            add(add(axis[1], g[1]), e.ground_follower_2_mm),
        ];
        let k_pin_q = [e.elbow_1_pin_q_mm, e.elbow_2_pin_q_mm];
        let k_pin_f = [add(g[0], e.elbow_1_pin_f_mm), add(g[1], e.elbow_2_pin_f_mm)];
        let k_pin_g = [add(h[0], e.elbow_1_pin_g_mm), add(h[1], e.elbow_2_pin_g_mm)];
        let t_pin_q = [
            add([T::ZERO, w2], e.platform_pin_d_mm),
            add([T::ZERO, -w2], e.platform_pin_e_mm),
        ];
        let t_pin_g = [
            add(add([T::ZERO, w2], h[0]), e.platform_pin_dd_mm),
            add(add([T::ZERO, -w2], h[1]), e.platform_pin_ee_mm),
        ];
        let bar = |p: BarEnd<T>, q: BarEnd<T>, len: T, section_mm2: T| Bar {
            p,
            q,
            length_mm: len,
            k_n_per_mm: design.youngs_modulus_n_per_mm2 * section_mm2 / len,
        };
        let (fs, ms) = (design.follower_bar_section_mm2, design.main_bar_section_mm2);
        // Nominal lengths: lever and first follower, distal bar and second follower, per arm.
        let (lever_mm, distal_mm) = ([nominal.a_mm, nominal.d_mm], [nominal.b_mm, nominal.c_mm]);
        let arm = |i: usize| {
            [
                bar(
                    BarEnd::Ground(follower[i]),
                    BarEnd::Body(i, k_pin_f[i]),
                    lever_mm[i] + e.bar_f_length_mm[i],
                    fs,
                ),
                bar(
                    BarEnd::Body(i, k_pin_q[i]),
                    BarEnd::Body(2, t_pin_q[i]),
                    distal_mm[i] + e.bar_q_length_mm[i],
                    ms,
                ),
                bar(
                    BarEnd::Body(i, k_pin_g[i]),
                    BarEnd::Body(2, t_pin_g[i]),
                    distal_mm[i] + e.bar_g_length_mm[i],
                    fs,
                ),
            ]
        };
        let (a1, a2) = (arm(0), arm(1));
        let lever = [
            lever_mm[0] + e.lever_length_mm[0],
            lever_mm[1] + e.lever_length_mm[1],
        ];
        // C = A0 + a·u1 + (K1's Q pin) + b·v1 - D_off: the equivalent five-bar's base A0' is
        // A0 + Q pin - D_off, its B0' likewise; the platform stays unrotated in the guess.
        let a0p = sub(add(motor[0], k_pin_q[0]), t_pin_q[0]);
        let b0p = sub(add(motor[1], k_pin_q[1]), t_pin_q[1]);
        let five = FiveBar {
            a_mm: lever[0],
            b_mm: a1[1].length_mm,
            c_mm: a2[1].length_mm,
            d_mm: lever[1],
            base_a0_mm: [T::ZERO; 2],
            base_b0_mm: sub(b0p, a0p),
            encoder_offset_rad: [T::ZERO; 2],
            mode: nominal.mode,
        };
        SixBarLayout {
            motor_mm: motor,
            lever_mm: lever,
            bars: [a1[0], a1[1], a1[2], a2[0], a2[1], a2[2]],
            five,
            five_base_mm: a0p,
        }
    }

    /// The lever tips A, B for geometric link angles (rad).
    pub fn lever_tips(&self, link_rad: [T; 2]) -> [[T; 2]; 2] {
        let mut t = [[T::ZERO; 2]; 2];
        for i in 0..2 {
            let (s, c) = link_rad[i].sin_cos();
            t[i] = [
                self.motor_mm[i][0] + self.lever_mm[i] * c,
                self.motor_mm[i][1] + self.lever_mm[i] * s,
            ];
        }
        t
    }

    /// The tool point of the equivalent five-bar (no stress) for link angles (rad).
    pub fn five_bar_tool_mm(&self, link_rad: [T; 2]) -> Result<[T; 2], KinematicsError> {
        Ok(add(
            self.five.forward(link_rad, T::ZERO)?,
            self.five_base_mm,
        ))
    }

    /// The rigid pose the closed-form equivalent five-bar gives: the unknowns `(x, y, φ)` of
    /// K1, K2 and T, the elbow pieces at the lever tips and nothing rotated.
    pub fn nominal_pose(&self, link_rad: [T; 2]) -> Result<[T; 9], KinematicsError> {
        let tips = self.lever_tips(link_rad);
        let c = self.five_bar_tool_mm(link_rad)?;
        Ok([
            tips[0][0],
            tips[0][1],
            T::ZERO,
            tips[1][0],
            tips[1][1],
            T::ZERO,
            c[0],
            c[1],
            T::ZERO,
        ])
    }
}

/// Limits a Levenberg-Marquardt step of the unknowns `(x, y, φ)` per body in place: no
/// translation beyond 1 mm and no rotation beyond 1/30 rad (rotations are compared as
/// displacements at a 30 mm lever), which keeps the solve inside the model's range. Returns the
/// step's size (mm) before the limit: what the solves' stopping rules compare.
pub fn limit_step<T: Real>(step: &mut [T]) -> T {
    let lever_mm = T::from_f64(30.0);
    let mut big = T::ZERO;
    for (k, v) in step.iter().enumerate() {
        let size = if k % 3 == 2 {
            v.abs() * lever_mm
        } else {
            v.abs()
        };
        big = big.max(size);
    }
    if big > T::ONE {
        for v in step.iter_mut() {
            *v = *v / big;
        }
    }
    big
}

/// Marquardt's damping `mu` after a step: relaxed tenfold after an accepted one (to none below
/// 1e-6: Gauss-Newton again), raised tenfold after a refused one (from 1e-4).
pub fn damping_after<T: Real>(mu: T, accepted: bool) -> T {
    let ten = T::from_f64(10.0);
    if accepted {
        if mu < T::from_f64(1e-6) {
            T::ZERO
        } else {
            mu / ten
        }
    } else if mu == T::ZERO {
        T::from_f64(1e-4)
    } else {
        mu * ten
    }
}

/// Energy `½k·dz(s)²` of a spring with a dead zone of half-width `c` (`dz(s) = s - c·tanh(s/c)`,
/// smooth, `≈ s³/3c²` inside the clearance): returns `(E, dE/ds, d²E/ds²)`; `dE/ds` is the
/// spring's force.
pub fn dead_zone_energy<T: Real>(s: T, c: T, k: T) -> (T, T, T) {
    if c <= T::ZERO {
        return (T::HALF * k * s * s, k * s, k);
    }
    let t = (s / c).tanh();
    let dz = s - c * t;
    let d1 = t * t;
    let d2 = T::TWO * t * (T::ONE - t * t) / c;
    (T::HALF * k * dz * dz, k * dz * d1, k * (d1 * d1 + dz * d2))
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// A step is limited by its largest translation or its largest rotation at the 30 mm
    /// lever, whichever is larger, and keeps its direction; a small one is left alone.
    #[test]
    fn a_step_is_limited_to_a_millimetre_or_a_thirtieth_of_a_radian() {
        let mut step = [0.5, -2.0, 0.1, 0.0, 0.0, 0.0, 0.25, 0.0, -0.01];
        assert_eq!(limit_step(&mut step), 3.0);
        assert_eq!(step[2], 0.1 / 3.0);
        assert_eq!(step[1], -2.0 / 3.0);
        let mut small = [0.5f32, 0.0, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!((limit_step(&mut small) - 0.6).abs() < 1e-6);
        assert_eq!(small[0], 0.5);
        // Damping: raised from none to 1e-4 and tenfold after refusals, relaxed tenfold after
        // an acceptance, to none below 1e-6.
        let mut mu = 0.0;
        for expected in [1e-4, 1e-3, 1e-2] {
            mu = damping_after(mu, false);
            assert!((mu - expected).abs() < 1e-15, "{mu}");
        }
        assert!((damping_after(mu, true) - 1e-3).abs() < 1e-15);
        assert_eq!(damping_after(5e-7, true), 0.0);
    }

    /// Without manufacturing errors the six-bar's equivalent five-bar is its nominal one, and
    /// at that five-bar's pose every bar sits at its own length (an error-free six-bar
    /// assembles without stress), over the workspace.
    #[test]
    fn an_error_free_six_bar_assembles_without_stress_at_its_five_bars_pose() {
        let nominal = FiveBar::<f64>::paper_nominal();
        let r = 30.0 * core::f64::consts::FRAC_1_SQRT_2;
        let design = SixBarDesign {
            nominal,
            platform_half_width_mm: 20.0,
            parallelogram_offsets_mm: [[[-r, r], [r, r]], [[-r, -r], [r, -r]]],
            youngs_modulus_n_per_mm2: 70_000.0,
            main_bar_section_mm2: 120.0,
            follower_bar_section_mm2: 40.0,
        };
        let layout = SixBarLayout::new(&design, &SixBarErrors::default());
        assert_eq!(layout.five, nominal);
        assert_eq!(layout.five_base_mm, [0.0; 2]);
        for target_mm in [[170.0, -70.0], [212.0, 10.0], [255.0, 60.0]] {
            let theta = nominal.inverse(target_mm, 0.0).unwrap();
            let pose = layout.nominal_pose(theta).unwrap();
            assert!((pose[6] - target_mm[0]).abs() < 1e-9 && (pose[7] - target_mm[1]).abs() < 1e-9);
            // Nothing is rotated in the pose: a pin on body b sits at the body's origin plus r.
            let world = |end: BarEnd<f64>| match end {
                BarEnd::Ground(p) => p,
                BarEnd::Body(b, r) => [pose[3 * b] + r[0], pose[3 * b + 1] + r[1]],
            };
            for (k, bar) in layout.bars.iter().enumerate() {
                let (p, q) = (world(bar.p), world(bar.q));
                let length_mm = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt();
                assert!(
                    (length_mm - bar.length_mm).abs() < 1e-9,
                    "bar {k} at {target_mm:?}: {length_mm} mm, built {} mm",
                    bar.length_mm
                );
            }
        }
    }
}
