//! The extended forward model over the data ([`Problem`]): the points prepared once, and the one
//! forward function that applies any subset of the library's effects ([`super::library`]).
//!
//! Prediction of the instrument reading for a measured pose (encoder angles θ, approach
//! directions dir, time t):
//!
//! ```text
//! θg_j = θ_j + offset_j(base model) + δθ_j − dir_j·β_j/2 + g_j·(θ_j − mean θ_j)
//!        [+ nuisance: A_j·cos(N_j θ_j) + B_j·sin(N_j θ_j)]
//! a' = a + δa,  d' = d + δd
//! b' = b + δb + Σ ks_i·s_b,i(θ),  c' = c + δc + (1 + kc/100)·Σ ks_i·s_c,i(θ)   (link_stretch)
//! B0' = B0 + (bx, by)
//! C = FK(...) + Σ pm_i·m_i(θ)                                         (parallelogram_mismatch)
//! reading = (1 + s)·R(φ)·C + (tx, ty)  [+ nuisance: (vx, vy)·(t − t0)]
//! ```
//!
//! The six-bar's own effects come from its linearised loop closure (`crate::loop_closure`,
//! reduced to a few modes over the data by `sixbar_modes.rs`): the overconstrained loops hold the
//! elbow pieces and the platform at a fixed orientation relative to the base, so a
//! parallelogram's misfit, the self-stress it causes and the bars' elastic elongation depend on
//! the absolute link angles θ1, θ2 (not only on the five-bar's shape, which on the paper
//! machine's rhombus made a shape-only stretch exactly link lengths + encoder offsets):
//! * `link_stretch`: s_b,i(θ), s_c,i(θ) are the elongations of the two distal bars under the
//!   self-stress modes (one self-stress drives both, in the design's ratio; unit RMS over the
//!   data and both bars: ks_i are RMS length changes, µm), and c's compliance relative to b's is
//!   free around the design's: `c' = c + δc + (1 + kc/100)·Σ ks_i·s_c,i(θ)`;
//! * `parallelogram_mismatch`: m_i(θ) are the dominant tool displacements of the loops' misfit
//!   (platform and elbow rotations, bearing deflections) that no constant five-bar parameter
//!   reproduces (unit RMS over the data: pm_i are RMS displacements, µm).
//!
//! Sign of backlash: a motor that last moved in +θ (dir = +1) drags the link behind it through
//! the lost motion, so the link sits β/2 short of the encoder angle; β > 0 is lost motion.
//!
//! The LM (`crate::numeric::lm`) fits it through [`Residuals`]: finite differences with a step of
//! 1e-2 in internal units (10 nm, 10 nrad, 0.01 ppm — far below every effect, far above rounding
//! at 200 mm).
//!
//! Cost: one closed-form FK per point per evaluation (a few hundred ns); no allocation per point.
//! A finite-difference column of a parameter that does not move the five-bar (frame, scale,
//! mismatch, drift, shape misfit) reuses the tool points ([`Residuals::neighbours`]): the
//! diagnosis tests take about a fifth less time, with the same bits.

use super::library::{idx, Effect, Nuisance, FIVE_BAR_SPAN, N_PARAMS, N_SHAPE};
use super::sixbar_modes::{self, SixBarModes, N_MISMATCH, N_STRETCH};
use crate::effect::PhysicalEffect;
use crate::io::measurement_csv::Measurement;
use crate::loop_closure::{SixBarDesign, N_RAW};
use crate::numeric::{finite_difference, Neighbours, Residuals};
use kinematics_core::{wrap_angle_rad, FiveBar};
use nalgebra::{DMatrix, DVector};

/// Smallest transmission |sin| of a usable point (about 0.06° from a singular configuration).
pub const MIN_TRANSMISSION: f64 = 1e-3;

/// Everything per point the forward model needs besides the parameters.
#[derive(Clone, Debug)]
pub struct Point {
    /// Index of the measurement this point came from (in the slice given to [`Problem::new`]).
    pub index: usize,
    pub theta_rad: [f64; 2],
    pub dir: [f64; 2],
    pub measured_mm: [f64; 2],
    /// The link_stretch basis: length change of b (arm 0) and c (arm 1) per µm of each mode.
    pub stretch_u: [[f64; N_STRETCH]; 2],
    /// The parallelogram_mismatch basis: tool displacement (µm) per µm of each mode.
    pub mismatch_um: [[f64; 2]; N_MISMATCH],
    /// The shape-misfit nuisance's basis (`diagnose::shape`): tool displacement (µm) per µm of
    /// each mode; zero unless the nuisance is set.
    pub shape_um: [[f64; 2]; N_SHAPE],
    /// θ_j minus its circular mean over the data, wrapped to (−π, π] (the gear_ratio basis), rad.
    pub theta_centred_rad: [f64; 2],
    /// Time since the first measurement (s; 0 without a time column).
    pub t_s: f64,
}

/// The data prepared once for all fits: points plus the base model.
#[derive(Clone, Debug)]
pub struct Problem {
    pub base: FiveBar<f64>,
    pub points: Vec<Point>,
    /// Every point has dir1/dir2.
    pub has_dir: bool,
    /// Every point has a time.
    pub has_time: bool,
    /// Points where the base model has no forward solution or is within [`MIN_TRANSMISSION`] of
    /// a singularity, or the six-bar built on it has no loop response (dropped, by file line).
    pub dropped_lines: Vec<usize>,
    /// The six-bar's design the loop-closure effects are derived from.
    pub design: SixBarDesign,
    /// The six-bar's modes over these points, or why they do not exist.
    pub sixbar: Result<SixBarModes, String>,
    /// The circular mean motor angles (the gear_ratio basis' centre), rad.
    pub mean_theta_rad: [f64; 2],
    /// Out-of-library structures fitted alongside every model.
    pub nuisance: Nuisance,
}

impl Problem {
    /// Prepares the points. Points the base model cannot reach are dropped (listed by line).
    pub fn new(base: FiveBar<f64>, design: &SixBarDesign, data: &[Measurement]) -> Problem {
        let has_dir = !data.is_empty() && data.iter().all(|m| m.dir.is_some());
        let has_time = !data.is_empty() && data.iter().all(|m| m.t_s.is_some());
        let t0 = data
            .iter()
            .filter_map(|m| m.t_s)
            .fold(f64::INFINITY, f64::min);
        let mut points = Vec::with_capacity(data.len());
        let mut responses = Vec::with_capacity(data.len());
        let mut dropped_lines = Vec::new();
        for (index, m) in data.iter().enumerate() {
            let th = m.theta_rad();
            // A point at (or within ~0.06° of) a singularity has unbounded sensitivities: dropped.
            if base.forward_pose(th, MIN_TRANSMISSION).is_err() {
                dropped_lines.push(m.line);
                continue;
            }
            let Ok(r) = crate::loop_closure::response(&base, design, th) else {
                dropped_lines.push(m.line);
                continue;
            };
            responses.push(r);
            let d = m
                .dir
                .map(|d| [d[0] as f64, d[1] as f64])
                .unwrap_or([0.0; 2]);
            points.push(Point {
                index,
                theta_rad: th,
                dir: d,
                measured_mm: m.measured_mm,
                stretch_u: [[0.0; N_STRETCH]; 2],
                mismatch_um: [[0.0; 2]; N_MISMATCH],
                shape_um: [[0.0; 2]; N_SHAPE],
                theta_centred_rad: [0.0; 2],
                t_s: if has_time {
                    m.t_s.unwrap_or(t0) - t0
                } else {
                    0.0
                },
            });
        }
        // Circular mean: the gear_ratio basis is θ about it, modulo 360° (Table I prints some
        // angles as θ + 360°; a plain mean would turn that bookkeeping into a huge "ratio error").
        let mean_theta_rad = [0, 1].map(|j| {
            let (s, c) = points.iter().fold((0.0, 0.0), |(s, c), p| {
                (s + p.theta_rad[j].sin(), c + p.theta_rad[j].cos())
            });
            s.atan2(c)
        });
        for p in points.iter_mut() {
            p.theta_centred_rad =
                [0, 1].map(|j| wrap_angle_rad(p.theta_rad[j] - mean_theta_rad[j]));
        }
        let mut problem = Problem {
            base,
            points,
            has_dir,
            has_time,
            dropped_lines,
            design: design.clone(),
            sixbar: Err("not computed".into()),
            mean_theta_rad,
            nuisance: Nuisance::default(),
        };
        problem.sixbar = problem
            .five_bar_span()
            .and_then(|f| sixbar_modes::modes(&responses, &f, &FIVE_BAR_SPAN));
        if let Ok(m) = &problem.sixbar {
            for (p, (s, d)) in problem
                .points
                .iter_mut()
                .zip(m.stretch.iter().zip(&m.mismatch_um))
            {
                p.stretch_u = *s;
                p.mismatch_um = *d;
            }
        }
        problem
    }

    /// The tool displacement (µm, x,y per point) per unit of each five-bar-span parameter.
    fn five_bar_span(&self) -> Result<DMatrix<f64>, String> {
        let j = finite_difference::jacobian(self, &[0.0; N_PARAMS], &FIVE_BAR_SPAN)
            .map_err(|_| "a point left the model's workspace while differentiating".to_string())?;
        // The residual is measured − predicted: the prediction's derivative is −J.
        Ok(-j)
    }

    /// Predicted instrument reading of point `p` with full parameter vector `x`.
    pub fn predict(&self, p: &Point, x: &[f64; N_PARAMS]) -> Option<[f64; 2]> {
        Some(self.reading_mm(p, x, &Instrument::of(x), self.tool_mm(p, x)?))
    }

    /// The five-bar part of [`Problem::predict`]: the tool point of the model with the
    /// parameters that [`moves_the_five_bar`] (lengths, offsets, base, backlash, stretch, gear
    /// ratio, periodic error); `None` where it has no FK.
    fn tool_mm(&self, p: &Point, x: &[f64; N_PARAMS]) -> Option<[f64; 2]> {
        let um = 1e-3;
        let urad = 1e-6;
        let mut m = self.base;
        let s = &p.stretch_u;
        m.a_mm += x[0] * um;
        let stretch = |arm: usize| -> f64 {
            (0..N_STRETCH)
                .map(|k| x[idx::STRETCH + k] * s[arm][k])
                .sum()
        };
        m.b_mm += (x[1] + stretch(0)) * um;
        m.c_mm += (x[2] + (1.0 + x[idx::STRETCH_RATIO] * 0.01) * stretch(1)) * um;
        m.d_mm += x[3] * um;
        m.base_b0_mm[0] += x[6] * um;
        m.base_b0_mm[1] += x[7] * um;
        let th = [0, 1].map(|j| {
            let mut t = p.theta_rad[j] + x[4 + j] * urad - p.dir[j] * x[8 + j] * urad * 0.5
                + x[idx::GEAR + j] * 1e-6 * p.theta_centred_rad[j];
            if let Some(n) = self.nuisance.cyclic_cycles[j] {
                let (sn, cs) = (n * p.theta_rad[j]).sin_cos();
                t += (x[idx::CYCLIC + 2 * j] * cs + x[idx::CYCLIC + 2 * j + 1] * sn) * urad;
            }
            t
        });
        m.forward(th, 0.0).ok()
    }

    /// The rest of [`Problem::predict`]: the tool point `tool_mm` with the six-bar's mismatch,
    /// the shape misfit, and through the instrument (`instrument`: `x`'s frame and scale) and
    /// its drift.
    fn reading_mm(
        &self,
        p: &Point,
        x: &[f64; N_PARAMS],
        instrument: &Instrument,
        tool_mm: [f64; 2],
    ) -> [f64; 2] {
        let um = 1e-3;
        let mut c = tool_mm;
        for (k, d) in p.mismatch_um.iter().enumerate() {
            c[0] += x[idx::MISMATCH + k] * d[0] * um;
            c[1] += x[idx::MISMATCH + k] * d[1] * um;
        }
        if self.nuisance.shape.is_some() {
            for (k, d) in p.shape_um.iter().enumerate() {
                c[0] += x[idx::SHAPE + k] * d[0] * um;
                c[1] += x[idx::SHAPE + k] * d[1] * um;
            }
        }
        let Instrument { sin, cos, scale } = *instrument;
        let drift = [
            x[idx::DRIFT] * p.t_s * 1e-3 * um,
            x[idx::DRIFT + 1] * p.t_s * 1e-3 * um,
        ];
        let t = [
            x[idx::FRAME] * um + drift[0],
            x[idx::FRAME + 1] * um + drift[1],
        ];
        [
            scale * (cos * c[0] - sin * c[1]) + t[0],
            scale * (sin * c[0] + cos * c[1]) + t[1],
        ]
    }

    /// Residuals (measured − predicted, µm), x then y per point; `None` if a point has no FK.
    pub fn residuals_um(&self, x: &[f64; N_PARAMS]) -> Option<Vec<f64>> {
        self.residuals_from(x, |p| self.tool_mm(p, x))
    }

    /// [`Problem::residuals_um`] with each point's tool point from `tool_mm`.
    fn residuals_from(
        &self,
        x: &[f64; N_PARAMS],
        mut tool_mm: impl FnMut(&Point) -> Option<[f64; 2]>,
    ) -> Option<Vec<f64>> {
        let mut r = Vec::with_capacity(2 * self.points.len());
        let instrument = Instrument::of(x);
        for p in &self.points {
            let c = self.reading_mm(p, x, &instrument, tool_mm(p)?);
            r.push((p.measured_mm[0] - c[0]) * 1e3);
            r.push((p.measured_mm[1] - c[1]) * 1e3);
        }
        Some(r)
    }

    /// Whether an effect can be fitted on these data (and why not).
    pub fn available(&self, e: &Effect) -> Result<(), String> {
        if e.needs_dir && !self.has_dir {
            return Err(format!(
                "{} skipped: the data have no dir1/dir2 columns",
                e.name()
            ));
        }
        if matches!(
            e.kind,
            PhysicalEffect::LinkStretch | PhysicalEffect::ParallelogramMismatch
        ) {
            if let Err(why) = &self.sixbar {
                return Err(format!("{} skipped: {why}", e.name()));
            }
        }
        Ok(())
    }

    /// The parameters free in a fit of `effects`: theirs, then the nuisances'.
    pub fn free_params(&self, effects: &[&Effect]) -> Vec<usize> {
        let mut p = super::library::params_of(effects);
        p.extend(self.nuisance.params());
        p
    }

    /// The effective six-bar errors (raw, µm; see `loop_closure`) a fitted parameter vector's
    /// link_stretch (per distal bar) and parallelogram_mismatch stand for, and the five-bar
    /// parameter change (by index) the mismatch modes' projection included with the opposite
    /// sign: what "add it to the model" writes.
    pub fn effective_sixbar(&self, x: &[f64]) -> Option<EffectiveSixBar> {
        let m = self.sixbar.as_ref().ok()?;
        let mut out = EffectiveSixBar {
            stretch_raw_um: [[0.0; N_RAW]; 2],
            mismatch_raw_um: [0.0; N_RAW],
            five_bar_shift: vec![0.0; N_PARAMS],
        };
        let ratio = [1.0, 1.0 + x[idx::STRETCH_RATIO] * 0.01];
        for (bar, r) in out.stretch_raw_um.iter_mut().zip(ratio) {
            for k in 0..N_STRETCH {
                let a = x[idx::STRETCH + k] * r;
                for (v, mode) in bar.iter_mut().zip(&m.stretch_raw[k]) {
                    *v += a * mode;
                }
            }
        }
        for k in 0..N_MISMATCH {
            let a = x[idx::MISMATCH + k];
            for raw in 0..N_RAW {
                out.mismatch_raw_um[raw] += a * m.mismatch_raw[k][raw];
            }
            for &(p, c) in &m.mismatch_five_bar[k] {
                out.five_bar_shift[p] -= a * c;
            }
        }
        Some(out)
    }
}

/// Finite-difference step of every parameter in internal units (module doc).
const FD_STEP: f64 = 1e-2;

impl Residuals for Problem {
    fn n_params(&self) -> usize {
        N_PARAMS
    }

    fn residuals(&self, p: &[f64]) -> Option<DVector<f64>> {
        let x: &[f64; N_PARAMS] = p.try_into().ok()?;
        self.residuals_um(x).map(DVector::from_vec)
    }

    fn fd_step(&self, _k: usize) -> f64 {
        FD_STEP
    }

    /// The tool points at `at` computed once, on the first neighbour that needs them, for
    /// every parameter that does not move the five-bar (see `moves_the_five_bar`; frame, scale,
    /// mismatch, drift, shape misfit: 30 of the 52): the FK and its sines are most of an
    /// evaluation, and a neighbour in those parameters has the same tool points, bit for bit.
    fn neighbours<'a>(&'a self, at: &[f64]) -> Neighbours<'a> {
        let at: Option<[f64; N_PARAMS]> = at.try_into().ok();
        let mut tools: Option<Option<Vec<[f64; 2]>>> = None;
        Box::new(move |q, k| {
            let x: &[f64; N_PARAMS] = q.try_into().ok()?;
            let Some(at) = at.as_ref().filter(|_| !moves_the_five_bar(k)) else {
                return self.residuals_um(x).map(DVector::from_vec);
            };
            let tools = tools
                .get_or_insert_with(|| self.points.iter().map(|p| self.tool_mm(p, at)).collect());
            let mut each = tools.as_ref()?.iter();
            self.residuals_from(x, |_| each.next().copied())
                .map(DVector::from_vec)
        })
    }
}

/// The instrument's rotation and scale of a parameter vector: the same for every point, so
/// computed once per evaluation.
#[derive(Clone, Copy, Debug)]
struct Instrument {
    sin: f64,
    cos: f64,
    scale: f64,
}

impl Instrument {
    fn of(x: &[f64; N_PARAMS]) -> Self {
        let (sin, cos) = (x[idx::FRAME + 2] * 1e-6).sin_cos();
        Instrument {
            sin,
            cos,
            scale: 1.0 + x[idx::SCALE] * 1e-6,
        }
    }
}

/// Whether parameter `k` changes the five-bar's tool point (the FK's input: lengths, encoder
/// offsets, base, backlash, stretch, gear ratio, periodic error) rather than only what is
/// added to it or how the instrument sees it.
fn moves_the_five_bar(k: usize) -> bool {
    k < idx::FRAME
        || (idx::GEAR..idx::MISMATCH).contains(&k)
        || (idx::CYCLIC..idx::DRIFT).contains(&k)
}

/// The six-bar part of a fitted model as effective errors (see [`Problem::effective_sixbar`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EffectiveSixBar {
    /// Raw errors whose distal-bar elongation is each bar's stretch.
    pub stretch_raw_um: [[f64; N_RAW]; 2],
    /// Raw errors whose loop response, less the distal stretch, is the mismatch.
    pub mismatch_raw_um: [f64; N_RAW],
    /// Five-bar parameter change (full parameter vector, problem units) that goes with the
    /// mismatch.
    pub five_bar_shift: Vec<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::library::{effect, PARAM_NAMES};
    use crate::loop_closure::response;
    use crate::numeric::subspace::max_cos;

    fn jacobian(p: &Problem, x: &[f64], cols: &[usize]) -> Option<DMatrix<f64>> {
        finite_difference::jacobian(p, x, cols).ok()
    }

    fn meas(theta_deg: [f64; 2], dir: [i8; 2], m: &FiveBar<f64>) -> Measurement {
        let c = m
            .forward([theta_deg[0].to_radians(), theta_deg[1].to_radians()], 0.0)
            .unwrap();
        Measurement {
            theta_deg,
            measured_mm: c,
            target_mm: None,
            dir: Some(dir),
            run: None,
            t_s: None,
            line: 0,
        }
    }

    fn grid(m: &FiveBar<f64>) -> Vec<Measurement> {
        let spec = crate::machine_spec::MachineSpec::paper();
        let (nominal, ws) = (spec.nominal, spec.workspace);
        let mut out = Vec::new();
        for i in 0..=10 {
            for j in 0..=10 {
                let t = [ws.x_mm[0] + 10.0 * i as f64, ws.y_mm[0] + 15.0 * j as f64];
                let th = nominal.inverse(t, spec.min_transmission).unwrap();
                out.push(meas(
                    [th[0].to_degrees(), th[1].to_degrees()],
                    [
                        if i % 2 == 0 { 1 } else { -1 },
                        if j % 2 == 0 { 1 } else { -1 },
                    ],
                    m,
                ));
            }
        }
        out
    }

    fn problem(data: &[Measurement]) -> Problem {
        Problem::new(FiveBar::paper_nominal(), &SixBarDesign::paper(), data)
    }

    /// A problem with every parameter in play: the periodic error and the shape misfit on,
    /// time and directions in the data, every parameter at a value of its own.
    fn every_parameter_in_play() -> (Problem, [f64; N_PARAMS]) {
        let mut data = grid(&FiveBar::paper_nominal());
        for (i, m) in data.iter_mut().enumerate() {
            m.t_s = Some(10.0 * i as f64);
            m.dir = Some([
                if i % 2 == 0 { 1 } else { -1 },
                if i % 3 == 0 { 1 } else { -1 },
            ]);
        }
        let mut p = problem(&data);
        p.nuisance.cyclic_cycles = [Some(17.0), Some(23.0)];
        p.nuisance.shape = Some((PhysicalEffect::LinkLengths, N_SHAPE));
        for (i, q) in p.points.iter_mut().enumerate() {
            for (k, d) in q.shape_um.iter_mut().enumerate() {
                *d = [((i + k) as f64).sin(), ((i * k) as f64).cos()];
            }
        }
        let x = std::array::from_fn(|k| 0.5 + 0.25 * k as f64);
        (p, x)
    }

    #[test]
    fn the_parameters_that_move_the_five_bar_are_those_its_fk_sees() {
        let (p, x) = every_parameter_in_play();
        for k in 0..N_PARAMS {
            let mut y = x;
            y[k] += 5.0;
            let tool_moved = p
                .points
                .iter()
                .any(|q| p.tool_mm(q, &x).unwrap() != p.tool_mm(q, &y).unwrap());
            let reading_moved = p
                .points
                .iter()
                .any(|q| p.predict(q, &x).unwrap() != p.predict(q, &y).unwrap());
            assert_eq!(tool_moved, moves_the_five_bar(k), "{}", PARAM_NAMES[k]);
            assert!(reading_moved, "{} changes nothing", PARAM_NAMES[k]);
        }
    }

    #[test]
    fn the_jacobian_through_the_shared_tool_points_is_the_plain_one_bit_for_bit() {
        let (p, x) = every_parameter_in_play();
        let all: Vec<usize> = (0..N_PARAMS).collect();
        let shared = jacobian(&p, &x, &all).unwrap();
        for k in all {
            let h = p.fd_step(k);
            let (mut hi, mut lo) = (x, x);
            hi[k] += h;
            lo[k] -= h;
            let column = (DVector::from_vec(p.residuals_um(&hi).unwrap())
                - DVector::from_vec(p.residuals_um(&lo).unwrap()))
                / (2.0 * h);
            assert_eq!(shared.column(k), column, "{}", PARAM_NAMES[k]);
        }
    }

    #[test]
    fn zero_parameters_reproduce_the_base_model() {
        let p = problem(&grid(&FiveBar::paper_nominal()));
        let r = p.residuals_um(&[0.0; N_PARAMS]).unwrap();
        assert!(r.iter().all(|v| v.abs() < 1e-9), "{:?}", &r[..4]);
    }

    #[test]
    fn library_offsets_and_lengths_match_the_five_bar_model() {
        let mut truth = FiveBar::<f64>::paper_nominal();
        truth.a_mm += 0.05;
        truth.encoder_offset_rad = [2e-4, -1e-4];
        truth.base_b0_mm = [0.03, -0.02];
        let p = problem(&grid(&truth));
        let mut x = [0.0; N_PARAMS];
        x[0] = 50.0;
        x[4] = 200.0;
        x[5] = -100.0;
        x[6] = 30.0;
        x[7] = -20.0;
        let r = p.residuals_um(&x).unwrap();
        assert!(r.iter().all(|v| v.abs() < 1e-6), "{:?}", &r[..4]);
    }

    #[test]
    fn backlash_sign_lags_the_approach_direction() {
        // dir = +1: the link sits β/2 short of the encoder angle.
        let base = FiveBar::<f64>::paper_nominal();
        let mut shifted = base;
        shifted.encoder_offset_rad = [-50e-6, 0.0];
        let mut data = vec![meas([45.0, -45.0], [1, 1], &shifted)];
        data[0].dir = Some([1, 1]);
        let p = problem(&data);
        let mut x = [0.0; N_PARAMS];
        x[8] = 100.0; // β1 = 100 µrad
        let r = p.residuals_um(&x).unwrap();
        assert!(r.iter().all(|v| v.abs() < 1e-6), "{r:?}");
        // One point: the six-bar's modes do not exist, and say why.
        assert!(p
            .available(effect("parallelogram_mismatch").unwrap())
            .is_err());
    }

    #[test]
    fn mismatch_modes_are_outside_the_five_bar_span_and_stretch_is_unit_rms() {
        let p = problem(&grid(&FiveBar::paper_nominal()));
        assert!(p.sixbar.is_ok(), "{:?}", p.sixbar.as_ref().err());
        let x = [0.0; N_PARAMS];
        let rigid = jacobian(&p, &x, &FIVE_BAR_SPAN).unwrap();
        let mismatch = jacobian(&p, &x, effect("parallelogram_mismatch").unwrap().params).unwrap();
        let cos = max_cos(&rigid, &mismatch);
        assert!(
            cos < 1e-6,
            "mismatch modes overlap the five-bar's parameters: cos {cos}"
        );
        // The stretch modes are physical length functions, partly what constant lengths and
        // offsets do (a constant stretch is a link length), but not wholly: their part outside
        // that span moves the tool by more than 1 % of the whole.
        let stretch = jacobian(&p, &x, effect("link_stretch").unwrap().params).unwrap();
        let svd = rigid.clone().svd(true, false);
        let (u, sv) = (svd.u.unwrap(), svd.singular_values);
        let keep: Vec<usize> = (0..sv.len()).filter(|&i| sv[i] > 1e-9 * sv.max()).collect();
        let q = nalgebra::DMatrix::from_fn(u.nrows(), keep.len(), |r, c| u[(r, keep[c])]);
        let outside = (&stretch - &q * (q.transpose() * &stretch)).norm() / stretch.norm();
        assert!(
            outside > 0.01,
            "stretch basis inside lengths+offsets: {outside}"
        );
        let n = p.points.len() as f64;
        for k in 0..N_STRETCH {
            let ms = p
                .points
                .iter()
                .map(|q| q.stretch_u[0][k].powi(2) + q.stretch_u[1][k].powi(2))
                .sum::<f64>()
                / (2.0 * n);
            assert!((ms.sqrt() - 1.0).abs() < 1e-9, "mode {k}: {}", ms.sqrt());
        }
        for k in 0..N_MISMATCH {
            let rms = (p
                .points
                .iter()
                .map(|q| q.mismatch_um[k][0].powi(2) + q.mismatch_um[k][1].powi(2))
                .sum::<f64>()
                / n)
                .sqrt();
            assert!((rms - 1.0).abs() < 1e-9, "mode {k}: {rms}");
        }
    }

    #[test]
    fn effective_sixbar_errors_reproduce_the_fitted_modes() {
        // What "add it to the model" writes (raw errors + five-bar shift), evaluated again by
        // the loop closure at every point, is the fitted modes' contribution.
        let p = problem(&grid(&FiveBar::paper_nominal()));
        let mut x = [0.0; N_PARAMS];
        x[idx::MISMATCH..idx::MISMATCH + 4].copy_from_slice(&[3.0, -2.0, 1.5, 0.7]);
        x[idx::STRETCH..idx::STRETCH + 6].copy_from_slice(&[4.0, -1.0, 2.5, 0.5, 0.2, 30.0]);
        let eff = p.effective_sixbar(&x).unwrap();
        // The five-bar shift's displacement, to first order (as the projection removed it).
        let j = jacobian(&p, &[0.0; N_PARAMS], &FIVE_BAR_SPAN).unwrap();
        let shift = nalgebra::DVector::from_iterator(
            FIVE_BAR_SPAN.len(),
            FIVE_BAR_SPAN.iter().map(|&k| eff.five_bar_shift[k]),
        );
        let five_bar_um = -(j * shift);
        for (i, q) in p.points.iter().enumerate() {
            let r = response(&p.base, &p.design, q.theta_rad).unwrap();
            let mut want = [0.0; 2];
            for (k, d) in q.mismatch_um.iter().enumerate() {
                want[0] += x[idx::MISMATCH + k] * d[0];
                want[1] += x[idx::MISMATCH + k] * d[1];
            }
            let mut got = [five_bar_um[2 * i], five_bar_um[2 * i + 1]];
            let mut stretch = [0.0; 2];
            for raw in 0..N_RAW {
                let m = eff.mismatch_raw_um[raw];
                let st = [0, 1].map(|arm| r.distal_elongation[arm][raw]);
                got[0] += m * (r.tool[raw][0] - r.dc_db[0][0] * st[0] - r.dc_db[1][0] * st[1]);
                got[1] += m * (r.tool[raw][1] - r.dc_db[0][1] * st[0] - r.dc_db[1][1] * st[1]);
                for (arm, s) in stretch.iter_mut().enumerate() {
                    *s += eff.stretch_raw_um[arm][raw] * r.distal_elongation[arm][raw];
                }
            }
            let err = (got[0] - want[0]).hypot(got[1] - want[1]);
            assert!(err < 1e-6, "point {i}: {got:?} vs {want:?}");
            for (arm, s) in stretch.iter().enumerate() {
                let ratio = if arm == 0 { 1.0 } else { 1.3 };
                let w: f64 = ratio
                    * (0..N_STRETCH)
                        .map(|k| x[idx::STRETCH + k] * q.stretch_u[arm][k])
                        .sum::<f64>();
                assert!((s - w).abs() < 1e-9, "point {i} arm {arm}: {s} vs {w}");
            }
        }
    }
}
