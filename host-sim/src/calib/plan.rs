//! The measurement session's target lists (`host-sim plan`): what to measure, in which order,
//! approached how, before a calibration starts. The simulated `measure` (`--targets`) and a
//! real session consume the same lists; the demo's pipeline measures exactly these.
//!
//! The lists ([`Plan`], each a [`Visit`] list; files: `crate::io::targets_csv`'s plan columns):
//! * `identify`: [`PlanOptions::identification_poses`] poses for the `full` fit, chosen for
//!   identifiability (below);
//! * `grid`: the machine's grid nodes in raster order (the `grid` protocol);
//! * `verify`: [`PlanOptions::verify_targets`] uniform random targets in the workspace, from a
//!   stream of their own, disjoint from every other list (a draw within
//!   [`DISJOINT_TOLERANCE_MM`] of another list's target is drawn again; none is, in practice);
//! * `repeat`: ISO 230-2 / VDI 3441 bidirectional runs along the two axis lines through the
//!   workspace's centre (the `repeat` protocol: 5 runs x 2 lines x 2 passes x 11 targets).
//!
//! Every row carries the approach the machine must use: the machine's policy
//! ([`MachineSpec::approach`]). `positive`: both motors arrive moving forward (`dir = +1,+1`);
//! `random`: the motion comes from `from_mm` (`approach_mm` away along a random direction,
//! or the previous node of a raster), and `dir` is the sign of each motor's change along it by
//! the nominal model.
//!
//! # Identification poses: a D-optimal design
//! Candidates: [`PlanOptions::candidates`] uniform random poses of the workspace (the stream
//! the demo drew its 40 fit poses from, so `--selection random` keeps those). The
//! identification Jacobian `J` of a pose set is the `full` fit's (`fit::params`: ∂ position /
//! ∂ the ten parameters, 2 rows per pose) at the nominal model, restricted to the parameters
//! the candidates identify (`fit::identifiability`). The selection maximises `det(JᵀJ)`
//! (D-optimality: the smallest joint confidence region of the parameters): greedy, adding the
//! candidate with the largest `det(I₂ + Jᵢ·M⁻¹·Jᵢᵀ)` (the determinant lemma; `M` starts as a
//! tiny ridge), then Fedorov exchange passes (swap a chosen pose for a candidate while the
//! determinant grows by more than 1e-9, at most [`MAX_EXCHANGE_PASSES`]). Reported against the
//! first N candidates (random poses of the same count): the condition number of the
//! column-scaled `J` (what `fit` reports as `condition_number_free`) and the observability
//! index O1 = (Π σᵢ)^(1/m) / √N of `J` with its columns scaled by the candidates' RMS (Borm &
//! Menq; the same scaling for both designs, so larger is better across them). Cost: one
//! Jacobian of the candidates (20 FK per pose) and ~`passes · N · candidates` 10x10 Cholesky
//! factorisations: well under a second for 40 of 400.

use super::fit::identifiability;
use super::fit::params;
use super::protocol::{random_visit, visits, Protocol, Range, Visit};
use super::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::io::targets_csv::ListedTarget;
use crate::machine_spec::{Approach, MachineSpec};
use crate::numeric::ScaledSvd;
use kinematics_core::wrap_angle_rad;
use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Identification poses by default (the demo's).
pub const IDENTIFICATION_POSES: usize = 40;
/// Candidate poses per identification pose, by default.
pub const CANDIDATES_PER_POSE: usize = 10;
/// Verification targets by default (the demo's).
pub const VERIFY_TARGETS: usize = 400;
/// Two targets closer than this (mm) are the same target.
pub const DISJOINT_TOLERANCE_MM: f64 = 1e-3;
/// Most exchange passes of the D-optimal selection.
pub const MAX_EXCHANGE_PASSES: usize = 20;
/// Most targets of any list.
pub const MAX_LIST_TARGETS: usize = 1_000_000;

/// How the identification poses are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Selection {
    /// Maximise det(JᵀJ) over the candidates (module doc).
    DOptimal,
    /// The first candidates: uniform random poses.
    Random,
}

/// What to plan.
#[derive(Clone, Debug)]
pub struct PlanOptions {
    pub spec: MachineSpec,
    /// Draws the candidates and the verification targets.
    pub seed: u64,
    pub identification_poses: usize,
    /// Candidate poses the identification poses are chosen from (≥ the poses).
    pub candidates: usize,
    pub selection: Selection,
    pub verify_targets: usize,
}

impl PlanOptions {
    /// The defaults for `spec` and `seed`: 40 D-optimal poses of 400 candidates, 400 targets.
    pub fn new(spec: MachineSpec, seed: u64) -> Self {
        PlanOptions {
            spec,
            seed,
            identification_poses: IDENTIFICATION_POSES,
            candidates: CANDIDATES_PER_POSE * IDENTIFICATION_POSES,
            selection: Selection::DOptimal,
            verify_targets: VERIFY_TARGETS,
        }
    }
}

/// How well a pose set identifies the model.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct DesignFigures {
    pub poses: usize,
    /// Condition number of the column-scaled identification Jacobian (free parameters).
    pub condition_number: f64,
    /// O1 = (Π σᵢ)^(1/m) / √N, columns scaled by the candidates' RMS (larger is better).
    pub observability_o1: f64,
    /// log10 det(JᵀJ) with the same scaling (larger is better).
    pub log10_det: f64,
}

/// The identification design against random poses of the same count.
#[derive(Clone, Debug, Serialize)]
pub struct IdentificationReport {
    pub selection: Selection,
    pub candidates: usize,
    /// The parameters the candidates identify (the design's columns).
    pub parameters: Vec<&'static str>,
    pub chosen: DesignFigures,
    pub random_same_count: DesignFigures,
    pub exchange_passes: usize,
}

/// What `plan` reports (`plan.json`).
#[derive(Clone, Debug, Serialize)]
pub struct PlanReport {
    pub machine: String,
    pub seed: u64,
    pub approach: Approach,
    pub approach_mm: f64,
    pub identification: IdentificationReport,
    /// Targets per list.
    pub lists: Vec<(&'static str, usize)>,
    /// Smallest distance from a verification target to a target of another list (mm).
    pub verify_min_distance_to_others_mm: f64,
}

/// The lists and the report.
#[derive(Clone, Debug)]
pub struct Plan {
    pub identify: Vec<Visit>,
    pub grid: Vec<Visit>,
    pub verify: Vec<Visit>,
    pub repeat: Vec<Visit>,
    pub report: PlanReport,
}

/// The lists' names (the file stems `plan` writes), in session order.
pub const LIST_NAMES: [&str; 4] = ["identify", "grid", "verify", "repeat"];

impl Plan {
    /// The lists by name ([`LIST_NAMES`]), in session order.
    pub fn lists(&self) -> [(&'static str, &[Visit]); 4] {
        [
            (LIST_NAMES[0], &self.identify),
            (LIST_NAMES[1], &self.grid),
            (LIST_NAMES[2], &self.verify),
            (LIST_NAMES[3], &self.repeat),
        ]
    }
}

/// The stream the identification candidates come from (the demo's historical fit poses).
fn candidate_rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed ^ 0xf17_f17)
}

/// The stream the verification targets come from (the demo's historical verification targets).
fn verify_rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed ^ 0x7e21_f1ed_0000)
}

/// The approach every visit of `list` must use under `spec`'s policy (module doc): `+1,+1`,
/// or each motor's direction from `from_mm` to the target by the nominal model (`+1` where the
/// model cannot reach the start).
pub fn with_approach(list: &mut [Visit], spec: &MachineSpec) -> Result<(), CalibError> {
    let m = &spec.nominal;
    for v in list.iter_mut() {
        v.dir = Some(match spec.approach {
            Approach::Positive => [1, 1],
            Approach::FromVisit => {
                let to = m.inverse(v.target_mm, spec.min_transmission).map_err(|e| {
                    CalibError::Target {
                        target_mm: v.target_mm,
                        reason: e.to_string(),
                    }
                })?;
                match m.inverse(v.from_mm, 0.0) {
                    Ok(from) => [0, 1].map(|i| {
                        if wrap_angle_rad(to[i] - from[i]) >= 0.0 {
                            1
                        } else {
                            -1
                        }
                    }),
                    Err(_) => [1, 1],
                }
            }
        });
    }
    Ok(())
}

/// Pseudo-measurements at `targets` for the Jacobian: the nominal model's angles, the target
/// as the measured point (the Jacobian does not depend on the residual).
fn poses_at(spec: &MachineSpec, targets: &[[f64; 2]]) -> Result<Vec<Measurement>, CalibError> {
    targets
        .iter()
        .map(|&t| {
            let th = spec
                .nominal
                .inverse(t, spec.min_transmission)
                .map_err(|e| CalibError::Target {
                    target_mm: t,
                    reason: e.to_string(),
                })?;
            Ok(Measurement {
                theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                measured_mm: t,
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: 0,
            })
        })
        .collect()
}

/// `Σ JᵢᵀJᵢ` of the chosen rows' pose blocks.
fn information(j: &DMatrix<f64>, chosen: &[usize]) -> DMatrix<f64> {
    let m = j.ncols();
    let mut info = DMatrix::zeros(m, m);
    for &i in chosen {
        let b = j.rows(2 * i, 2);
        info += b.transpose() * b;
    }
    info
}

/// `ln det` of a symmetric matrix (−∞ if not positive definite).
fn ln_det(a: &DMatrix<f64>) -> f64 {
    match a.clone().cholesky() {
        Some(c) => 2.0 * c.l().diagonal().iter().map(|d| d.ln()).sum::<f64>(),
        None => f64::NEG_INFINITY,
    }
}

/// The design figures of the poses `chosen` (rows of `j`, scaled by the candidates' RMS).
fn figures(j_scaled: &DMatrix<f64>, chosen: &[usize]) -> DesignFigures {
    let rows: Vec<usize> = chosen.iter().flat_map(|&i| [2 * i, 2 * i + 1]).collect();
    let sub = j_scaled.select_rows(&rows);
    let condition_number = 1.0 / ScaledSvd::new(&sub).min_relative();
    let sv = sub.clone().svd(false, false).singular_values;
    let m = sv.len() as f64;
    let n = chosen.len() as f64;
    let ln_prod: f64 = sv.iter().map(|s| s.max(f64::MIN_POSITIVE).ln()).sum();
    DesignFigures {
        poses: chosen.len(),
        condition_number,
        observability_o1: (ln_prod / m).exp() / n.sqrt(),
        log10_det: 2.0 * ln_prod / std::f64::consts::LN_10,
    }
}

/// Chooses `n` of the candidate rows of `j` (2 rows each) maximising det(JᵀJ) (module doc).
/// Returns the chosen candidates (ascending) and the exchange passes run.
fn d_optimal(j: &DMatrix<f64>, n: usize) -> (Vec<usize>, usize) {
    let (count, m) = (j.nrows() / 2, j.ncols());
    let block = |i: usize| j.rows(2 * i, 2).into_owned();
    // Greedy from a tiny ridge: each step the candidate adding the most information.
    let scale =
        (0..m).map(|c| j.column(c).norm_squared()).sum::<f64>() / (count.max(1) as f64 * m as f64);
    let mut info = DMatrix::<f64>::identity(m, m) * (1e-9 * scale.max(f64::MIN_POSITIVE));
    let mut chosen: Vec<usize> = Vec::with_capacity(n);
    let mut taken = vec![false; count];
    for _ in 0..n {
        let Some(inv) = info.clone().try_inverse() else {
            break;
        };
        let mut best = (f64::NEG_INFINITY, usize::MAX);
        for i in (0..count).filter(|&i| !taken[i]) {
            let b = block(i);
            let g = DMatrix::<f64>::identity(2, 2) + &b * &inv * b.transpose();
            let d = g[(0, 0)] * g[(1, 1)] - g[(0, 1)] * g[(1, 0)];
            if d > best.0 {
                best = (d, i);
            }
        }
        if best.1 == usize::MAX {
            break;
        }
        taken[best.1] = true;
        chosen.push(best.1);
        let b = block(best.1);
        info += b.transpose() * &b;
    }
    // Fedorov exchange on the exact information matrix.
    let mut info = information(j, &chosen);
    let mut current = ln_det(&info);
    let mut passes = 0;
    for _ in 0..MAX_EXCHANGE_PASSES {
        passes += 1;
        let mut improved = false;
        for slot in chosen.iter_mut() {
            let s = *slot;
            let bs = block(s);
            let without = &info - bs.transpose() * &bs;
            let mut best = (current, usize::MAX);
            for c in (0..count).filter(|&c| !taken[c]) {
                let bc = block(c);
                let v = ln_det(&(&without + bc.transpose() * &bc));
                if v > best.0 + 1e-9 {
                    best = (v, c);
                }
            }
            if best.1 != usize::MAX {
                taken[s] = false;
                taken[best.1] = true;
                *slot = best.1;
                let bc = block(best.1);
                info = without + bc.transpose() * &bc;
                current = best.0;
                improved = true;
            }
        }
        if !improved {
            break;
        }
    }
    chosen.sort_unstable();
    (chosen, passes)
}

/// The identification poses and their report.
fn identification(opts: &PlanOptions) -> Result<(Vec<Visit>, IdentificationReport), CalibError> {
    let spec = &opts.spec;
    let mut rng = candidate_rng(opts.seed);
    let candidates: Vec<Visit> = (0..opts.candidates)
        .map(|_| random_visit(&mut rng, spec, Range::HalfOpen))
        .collect();
    let targets: Vec<[f64; 2]> = candidates.iter().map(|v| v.target_mm).collect();
    let poses = poses_at(spec, &targets)?;
    let j_all = params::jacobian(&spec.nominal, &poses)
        .map_err(|e| invalid!("the identification Jacobian: {e}"))?;
    let free = identifiability::check(&j_all, &[]).free;
    let mut j = j_all.select_columns(&free);
    // Scale every column by its RMS over the candidates: unit-free, the same for every design.
    for mut c in j.column_iter_mut() {
        let rms = (c.norm_squared() / (poses.len() as f64)).sqrt();
        if rms > 0.0 {
            c /= rms;
        }
    }
    let n = opts.identification_poses;
    let random: Vec<usize> = (0..n).collect();
    let (chosen, passes) = match opts.selection {
        Selection::Random => (random.clone(), 0),
        Selection::DOptimal => d_optimal(&j, n),
    };
    if chosen.len() != n {
        return Err(invalid!(
            "could choose only {} identification poses of {n}",
            chosen.len()
        ));
    }
    let report = IdentificationReport {
        selection: opts.selection,
        candidates: opts.candidates,
        parameters: free.iter().map(|&k| params::NAMES[k]).collect(),
        chosen: figures(&j, &chosen),
        random_same_count: figures(&j, &random),
        exchange_passes: passes,
    };
    Ok((chosen.iter().map(|&i| candidates[i]).collect(), report))
}

/// A list as a targets file holds it (`crate::io::targets_csv`, the plan's columns).
pub fn list_rows(list: &[Visit]) -> Vec<ListedTarget> {
    list.iter()
        .map(|v| ListedTarget {
            line: 0,
            target_mm: v.target_mm,
            from_mm: Some(v.from_mm),
            dir: v.dir,
            run: Some(v.run),
        })
        .collect()
}

/// The visits of a targets file's rows: each row's approach start, or the previous row's target
/// (a list measured in order; the first from `approach_mm` before it along −x); its run or 0;
/// its motor directions or none (then the measurement's policy decides).
pub fn visits_from_rows(rows: &[ListedTarget], spec: &MachineSpec) -> Vec<Visit> {
    let mut previous: Option<[f64; 2]> = None;
    rows.iter()
        .map(|r| {
            let t = r.target_mm;
            let from_mm = r
                .from_mm
                .or(previous)
                .unwrap_or([t[0] - spec.approach_mm, t[1]]);
            previous = Some(t);
            Visit {
                target_mm: t,
                from_mm,
                run: r.run.unwrap_or(0),
                dir: r.dir,
            }
        })
        .collect()
}

/// Distance from `p` to the nearest target of `lists` (mm).
fn nearest_mm(p: [f64; 2], lists: &[&[Visit]]) -> f64 {
    lists
        .iter()
        .flat_map(|l| l.iter())
        .map(|v| (v.target_mm[0] - p[0]).hypot(v.target_mm[1] - p[1]))
        .fold(f64::INFINITY, f64::min)
}

/// Plans the session (module doc).
pub fn plan(opts: &PlanOptions) -> Result<Plan, CalibError> {
    let spec = &opts.spec;
    spec.validate()
        .map_err(|e| invalid!("machine '{}': {e}", spec.name))?;
    let n = opts.identification_poses;
    if !(6..=MAX_LIST_TARGETS).contains(&n) {
        return Err(invalid!("{n} identification poses: the full fit needs at least 6 (12 equations for 10 parameters), at most {MAX_LIST_TARGETS}"));
    }
    if opts.candidates < n || opts.candidates > MAX_LIST_TARGETS {
        return Err(invalid!("{} candidates for {n} identification poses: need at least as many as the poses, at most {MAX_LIST_TARGETS}", opts.candidates));
    }
    if opts.verify_targets == 0 || opts.verify_targets > MAX_LIST_TARGETS {
        return Err(invalid!(
            "{} verification targets: need 1..={MAX_LIST_TARGETS}",
            opts.verify_targets
        ));
    }
    let (mut identify, identification) = identification(opts)?;
    let mut grid = visits(Protocol::Grid, opts.seed, spec);
    let mut repeat = visits(Protocol::Repeat, opts.seed, spec);
    let mut rng = verify_rng(opts.seed);
    let mut verify = Vec::with_capacity(opts.verify_targets);
    while verify.len() < opts.verify_targets {
        let v = random_visit(&mut rng, spec, Range::HalfOpen);
        if nearest_mm(v.target_mm, &[&identify, &grid, &repeat]) > DISJOINT_TOLERANCE_MM {
            verify.push(v);
        }
    }
    for list in [&mut identify, &mut grid, &mut verify, &mut repeat] {
        with_approach(list, spec)?;
    }
    let min_distance = verify
        .iter()
        .map(|v| nearest_mm(v.target_mm, &[&identify, &grid, &repeat]))
        .fold(f64::INFINITY, f64::min);
    let report = PlanReport {
        machine: spec.name.clone(),
        seed: opts.seed,
        approach: spec.approach,
        approach_mm: spec.approach_mm,
        identification,
        lists: vec![
            ("identify", identify.len()),
            ("grid", grid.len()),
            ("verify", verify.len()),
            ("repeat", repeat.len()),
        ],
        verify_min_distance_to_others_mm: min_distance,
    };
    Ok(Plan {
        identify,
        grid,
        verify,
        repeat,
        report,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::targets_csv::{format_target_list, parse_target_list};

    #[test]
    fn the_plan_of_the_paper_machine() {
        let p = plan(&PlanOptions::new(MachineSpec::paper(), 1)).unwrap();
        assert_eq!(
            (
                p.identify.len(),
                p.grid.len(),
                p.verify.len(),
                p.repeat.len()
            ),
            (40, 651, 400, 220)
        );
        // Every row says how to approach: the paper machine positions unidirectionally.
        for (_, list) in p.lists() {
            assert!(list.iter().all(|v| v.dir == Some([1, 1])));
        }
        // Disjoint: no verification target is a target of another list.
        assert!(p.report.verify_min_distance_to_others_mm > DISJOINT_TOLERANCE_MM);
        // The chosen poses identify the model better than random poses of the same count.
        let id = &p.report.identification;
        eprintln!("{id:?}");
        assert!(
            id.chosen.condition_number < id.random_same_count.condition_number,
            "{id:?}"
        );
        assert!(
            id.chosen.observability_o1 > id.random_same_count.observability_o1,
            "{id:?}"
        );
        assert!(
            id.chosen.log10_det > id.random_same_count.log10_det,
            "{id:?}"
        );
        // Distinct poses, every one inside the workspace.
        for (k, v) in p.identify.iter().enumerate() {
            assert!(MachineSpec::paper().workspace.contains(v.target_mm, 0.0));
            assert!(p.identify[k + 1..]
                .iter()
                .all(|w| w.target_mm != v.target_mm));
        }
    }

    #[test]
    fn random_selection_keeps_the_first_candidates_and_the_same_seed_the_same_plan() {
        let spec = MachineSpec::paper();
        let mut o = PlanOptions::new(spec.clone(), 5);
        o.selection = Selection::Random;
        let p = plan(&o).unwrap();
        let mut rng = candidate_rng(5);
        let first: Vec<[f64; 2]> = (0..40)
            .map(|_| random_visit(&mut rng, &spec, Range::HalfOpen).target_mm)
            .collect();
        assert_eq!(
            p.identify.iter().map(|v| v.target_mm).collect::<Vec<_>>(),
            first
        );
        assert_eq!(
            p.report.identification.chosen,
            p.report.identification.random_same_count
        );
        let a = plan(&PlanOptions::new(spec.clone(), 5)).unwrap();
        let b = plan(&PlanOptions::new(spec, 5)).unwrap();
        assert_eq!(a.identify, b.identify);
        assert_eq!(a.verify, b.verify);
    }

    #[test]
    fn a_random_approach_policy_gives_each_motor_its_direction() {
        let mut spec = MachineSpec::paper();
        spec.approach = Approach::FromVisit;
        let p = plan(&PlanOptions::new(spec, 2)).unwrap();
        let mut seen = std::collections::HashSet::new();
        for v in &p.verify {
            seen.insert(v.dir.unwrap());
        }
        assert_eq!(seen.len(), 4, "{seen:?}");
    }

    #[test]
    fn the_lists_survive_their_files() {
        let p = plan(&PlanOptions::new(MachineSpec::paper(), 3)).unwrap();
        for (name, list) in p.lists() {
            let back = parse_target_list(&format_target_list(&list_rows(list))).unwrap();
            assert_eq!(
                visits_from_rows(&back, &MachineSpec::paper()),
                list,
                "{name}"
            );
        }
    }

    #[test]
    fn bad_options_are_refused() {
        let mut o = PlanOptions::new(MachineSpec::paper(), 1);
        o.identification_poses = 3;
        assert!(plan(&o).unwrap_err().to_string().contains("at least 6"));
        let mut o = PlanOptions::new(MachineSpec::paper(), 1);
        o.candidates = 10;
        assert!(plan(&o).unwrap_err().to_string().contains("candidates"));
        let mut o = PlanOptions::new(MachineSpec::paper(), 1);
        o.verify_targets = 0;
        assert!(plan(&o).is_err());
    }
}
