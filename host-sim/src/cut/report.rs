//! The figures of a cut, measured on the executed motion (never on the plan): the contour error
//! at the tool while the beam is on, whether the micro stayed inside its workspace less the
//! margin, each stage's peaks against its limits; with the plan's times, the baseline's and the
//! bound. And the executed trajectories as CSV.
//!
//! How each figure is measured:
//! * **Contour error:** at every sample with the beam on, the distance from where the tool
//!   really is (gantry + micro, both plants) to the programmed path: the nearest of the cut
//!   moves around the one the plan is on (the previous, this, the next), or the point where the
//!   tool rests (a pierce).
//! * **Speed, acceleration:** central differences of the executed positions (the gantry per
//!   axis, the micro's offset as a norm); **jerk** (gantry): the second difference of the
//!   velocity over [`JERK_WINDOW_S`], the window the limit is stated over.
//! * **Joints:** the micro's joint speeds from its drives, its torques as commanded.

use super::execute::Executed;
use super::limits::JERK_WINDOW_S;
use super::split::PlanMode;
use super::{MachineLimits, Planned};
use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use serde::Serialize;

/// The gantry's executed peaks against its limits.
#[derive(Clone, Debug, Serialize)]
pub struct GantryFigures {
    pub peak_speed_mm_s: [f64; 2],
    pub peak_accel_mm_s2: [f64; 2],
    pub peak_jerk_mm_s3: [f64; 2],
    pub limit_speed_mm_s: f64,
    pub limit_accel_mm_s2: f64,
    pub limit_jerk_mm_s3: f64,
    /// Largest |reference − position| (µm): what the micro compensated.
    pub max_following_error_um: f64,
    pub inside_travel: bool,
}

/// The micro's executed peaks against its limits.
#[derive(Clone, Debug, Serialize)]
pub struct MicroFigures {
    pub peak_speed_mm_s: f64,
    pub peak_accel_mm_s2: f64,
    pub peak_joint_speed_rad_s: f64,
    pub peak_torque_nm: f64,
    pub limit_speed_mm_s: f64,
    pub limit_accel_mm_s2: f64,
    pub limit_joint_speed_rad_s: f64,
    pub limit_torque_nm: [f64; 2],
    /// Largest excursion from the workspace centre (mm, per axis).
    pub max_excursion_mm: [f64; 2],
    /// The smallest distance to the workspace's edge less the margin (mm; < 0: left it).
    pub min_clearance_mm: f64,
}

/// Which machine a file is of.
#[derive(Clone, Debug, Serialize)]
pub struct MachineId {
    pub name: String,
    /// 8 hex digits; empty when the machine has no record (a name the controller cannot store).
    pub digest: String,
}

impl MachineId {
    /// The name and digest of `spec`.
    pub fn of(spec: &MachineSpec) -> MachineId {
        MachineId {
            name: spec.name.clone(),
            digest: spec
                .record()
                .map(|r| format!("{:08x}", r.digest()))
                .unwrap_or_default(),
        }
    }
}

/// What a cut reports (`host-sim cut` prints it as JSON).
#[derive(Clone, Debug, Serialize)]
pub struct CutReport {
    pub program: String,
    /// The machine: its name and digest (the record's CRC-32C of its geometry).
    pub machine: MachineId,
    /// `split` or `gantry-only`.
    pub plan: PlanMode,
    /// Why the plan is the gantry alone, if it is.
    pub fallback: Option<String>,
    /// When the tool's program ends, as executed on the common time base (s).
    pub completion_s: f64,
    /// The same program on the gantry alone, same limits (s).
    pub gantry_only_s: f64,
    /// No plan with these limits is faster (s).
    pub bound_s: f64,
    /// `gantry_only_s / completion_s`.
    pub speedup: f64,
    /// `completion_s / bound_s`.
    pub bound_ratio: f64,
    /// The tool's distance from the programmed path while the beam is on (µm).
    pub contour_max_um: f64,
    pub contour_rms_um: f64,
    /// The micro never left its workspace less the margin.
    pub micro_inside_workspace: bool,
    /// No stage exceeded a limit (the executed motion).
    pub within_limits: bool,
    /// Each limit exceeded, named.
    pub violations: Vec<String>,
    pub gantry: GantryFigures,
    pub micro: MicroFigures,
    /// When the gantry is at rest at the end too (s).
    pub gantry_settled_s: f64,
    /// How long the gantry starts before the tool (s).
    pub lead_s: f64,
    /// The split filter's windows `[x, y]` × `[n₁, n₂]` (s).
    pub windows_s: [[f64; 2]; 2],
    pub rounds: usize,
    pub slowed_spans: usize,
    pub moves: usize,
    pub spans: usize,
    pub pierces: usize,
    pub cut_length_mm: f64,
    pub rapid_length_mm: f64,
    pub laser_on_s: f64,
    pub samples: usize,
    pub sample_period_s: f64,
    /// Wall time of the planning and of the execution (s).
    pub planner_s: f64,
    pub execution_s: f64,
    /// What ran the micro.
    pub micro_stage: String,
}

/// What [`report`] measures.
pub struct ReportInputs<'a> {
    pub name: &'a str,
    pub spec: &'a MachineSpec,
    pub planned: &'a Planned,
    pub limits: &'a MachineLimits,
    pub executed: &'a [Executed],
    pub stage: &'a str,
    pub execution_s: f64,
}

/// The depth of `p` inside the convex polygon `v` (counter-clockwise; negative outside).
fn depth_mm(v: &[[f64; 2]], p: [f64; 2]) -> f64 {
    let mut d = f64::INFINITY;
    for (i, a) in v.iter().enumerate() {
        let b = v[(i + 1) % v.len()];
        let e = [b[0] - a[0], b[1] - a[1]];
        let l = e[0].hypot(e[1]);
        if l > 0.0 {
            d = d.min((-(e[1]) * (p[0] - a[0]) + e[0] * (p[1] - a[1])) / l);
        }
    }
    d
}

/// The contour error of every sample (µm; `None` with the beam off).
pub fn contour_errors_um(planned: &Planned, executed: &[Executed]) -> Vec<Option<f64>> {
    let moves = &planned.layout.moves;
    let plan = &planned.plan;
    executed
        .iter()
        .enumerate()
        .map(|(k, e)| {
            if !e.laser_on {
                return None;
            }
            let q = e.tool_mm();
            let i = e.move_index as usize;
            let mut d = f64::INFINITY;
            let near = i.saturating_sub(1)..=(i + 1).min(moves.len().saturating_sub(1));
            for m in moves[near].iter().filter(|m| m.laser_on) {
                d = d.min(m.segment.distance_mm(q));
            }
            if !d.is_finite() {
                let p = plan.tool_mm[k];
                d = (q[0] - p[0]).hypot(q[1] - p[1]);
            }
            Some(d * 1e3)
        })
        .collect()
}

/// The figures of a cut (module doc).
pub fn report(r: &ReportInputs<'_>) -> CutReport {
    let (planned, ex) = (r.planned, r.executed);
    let plan = &planned.plan;
    let dt = plan.dt_s;
    let lim = &r.limits.split;
    let g = &r.spec.gantry;
    let micro = &lim.micro;
    let mut violations = Vec::new();
    // Contour error.
    let errs = contour_errors_um(planned, ex);
    let on: Vec<f64> = errs.iter().flatten().copied().collect();
    let contour_max_um = on.iter().fold(0.0f64, |m, x| m.max(*x));
    let contour_rms_um = if on.is_empty() {
        0.0
    } else {
        (on.iter().map(|x| x * x).sum::<f64>() / on.len() as f64).sqrt()
    };
    // The gantry.
    let n = ex.len();
    let gp = |k: usize| ex[k.min(n - 1)].gantry_mm;
    let mut gv = vec![[0.0; 2]; n];
    let (mut ps, mut pa, mut pj) = ([0.0f64; 2], [0.0f64; 2], [0.0f64; 2]);
    for (k, v) in gv.iter_mut().enumerate().take(n.saturating_sub(1)).skip(1) {
        let (a, b, c) = (gp(k - 1), gp(k), gp(k + 1));
        for i in 0..2 {
            v[i] = (c[i] - a[i]) / (2.0 * dt);
            ps[i] = ps[i].max(v[i].abs());
            pa[i] = pa[i].max(((c[i] - 2.0 * b[i] + a[i]) / (dt * dt)).abs());
        }
    }
    let w = ((JERK_WINDOW_S / dt).round() as usize).max(1);
    let tw = w as f64 * dt;
    for k in w..n.saturating_sub(w) {
        for i in 0..2 {
            let j = (gv[k + w][i] - 2.0 * gv[k][i] + gv[k - w][i]) / (tw * tw);
            pj[i] = pj[i].max(j.abs());
        }
    }
    let ga = g.accel_g * STANDARD_GRAVITY_MM_S2;
    for i in 0..2 {
        let axis = ["x", "y"][i];
        if ps[i] > g.speed_mm_s {
            violations.push(format!(
                "gantry {axis} speed {:.1} > {} mm/s",
                ps[i], g.speed_mm_s
            ));
        }
        if pa[i] > ga {
            violations.push(format!(
                "gantry {axis} acceleration {:.0} > {ga:.0} mm/s²",
                pa[i]
            ));
        }
        if pj[i] > g.jerk_mm_s3 {
            violations.push(format!(
                "gantry {axis} jerk {:.0} > {:.0} mm/s³",
                pj[i], g.jerk_mm_s3
            ));
        }
    }
    let inside_travel = ex.iter().all(|e| g.in_travel(e.gantry_mm));
    if !inside_travel {
        violations.push("the gantry left its travel".into());
    }
    let max_following_error_um = ex
        .iter()
        .zip(&plan.gantry_mm)
        .map(|(e, r)| (e.gantry_mm[0] - r[0]).hypot(e.gantry_mm[1] - r[1]))
        .fold(0.0f64, f64::max)
        * 1e3;
    // The micro.
    let mp = |k: usize| ex[k.min(n - 1)].micro_mm;
    let (mut ms, mut ma) = (0.0f64, 0.0f64);
    for k in 1..n.saturating_sub(1) {
        let (a, b, c) = (mp(k - 1), mp(k), mp(k + 1));
        let v = [(c[0] - a[0]) / (2.0 * dt), (c[1] - a[1]) / (2.0 * dt)];
        let acc = [
            (c[0] - 2.0 * b[0] + a[0]) / (dt * dt),
            (c[1] - 2.0 * b[1] + a[1]) / (dt * dt),
        ];
        ms = ms.max(v[0].hypot(v[1]));
        ma = ma.max(acc[0].hypot(acc[1]));
    }
    let verts = micro.region.vertices_mm();
    let (mut clearance, mut excursion) = (f64::INFINITY, [0.0f64; 2]);
    let (mut joint, mut torque) = (0.0f64, 0.0f64);
    let mut torque_over = false;
    for e in ex {
        let p = [
            micro.centre_mm[0] + e.micro_mm[0],
            micro.centre_mm[1] + e.micro_mm[1],
        ];
        clearance = clearance.min(depth_mm(verts, p) - micro.margin_mm);
        for (i, x) in excursion.iter_mut().enumerate() {
            *x = x.max(e.micro_mm[i].abs());
            joint = joint.max(f64::from(e.joint_speed_rad_s[i].abs()));
            let t = f64::from(e.torque_nm[i].abs());
            torque = torque.max(t);
            torque_over |= t >= micro.torque_limit_nm[i];
        }
    }
    if ms > micro.speed_mm_s {
        violations.push(format!(
            "micro speed {ms:.1} > {:.1} mm/s",
            micro.speed_mm_s
        ));
    }
    if ma > micro.accel_mm_s2 {
        violations.push(format!(
            "micro acceleration {ma:.0} > {:.0} mm/s²",
            micro.accel_mm_s2
        ));
    }
    if joint > micro.joint_speed_rad_s {
        violations.push(format!(
            "micro joint speed {joint:.2} > {} rad/s",
            micro.joint_speed_rad_s
        ));
    }
    if torque_over {
        violations.push(format!("micro torque reached its limit ({torque:.2} N·m)"));
    }
    let micro_inside_workspace = clearance >= 0.0;
    if !micro_inside_workspace {
        violations.push(format!(
            "the micro left its workspace less the margin by {:.3} mm",
            -clearance
        ));
    }
    let layout = &planned.layout;
    let (mut cut, mut rapid) = (0.0, 0.0);
    for m in &layout.moves {
        if m.laser_on {
            cut += m.segment.length_mm();
        } else if matches!(m.kind, super::gcode::MoveKind::Rapid) {
            rapid += m.segment.length_mm();
        }
    }
    let pierces = planned
        .program
        .ops
        .iter()
        .filter(|o| matches!(o, super::gcode::Op::Laser { on: true, .. }))
        .count();
    let completion_s = plan.completion_s();
    CutReport {
        program: r.name.to_string(),
        machine: MachineId::of(r.spec),
        plan: plan.mode,
        fallback: plan.fallback.clone(),
        completion_s,
        gantry_only_s: planned.gantry_only_s,
        bound_s: planned.bound.bound_s,
        speedup: planned.gantry_only_s / completion_s.max(1e-12),
        bound_ratio: completion_s / planned.bound.bound_s.max(1e-12),
        contour_max_um,
        contour_rms_um,
        micro_inside_workspace,
        within_limits: violations.is_empty(),
        violations,
        gantry: GantryFigures {
            peak_speed_mm_s: ps,
            peak_accel_mm_s2: pa,
            peak_jerk_mm_s3: pj,
            limit_speed_mm_s: g.speed_mm_s,
            limit_accel_mm_s2: ga,
            limit_jerk_mm_s3: g.jerk_mm_s3,
            max_following_error_um,
            inside_travel,
        },
        micro: MicroFigures {
            peak_speed_mm_s: ms,
            peak_accel_mm_s2: ma,
            peak_joint_speed_rad_s: joint,
            peak_torque_nm: torque,
            limit_speed_mm_s: micro.speed_mm_s,
            limit_accel_mm_s2: micro.accel_mm_s2,
            limit_joint_speed_rad_s: micro.joint_speed_rad_s,
            limit_torque_nm: micro.torque_limit_nm,
            max_excursion_mm: excursion,
            min_clearance_mm: clearance,
        },
        gantry_settled_s: plan.samples().saturating_sub(1) as f64 * dt,
        lead_s: plan.lead as f64 * dt,
        windows_s: plan.windows_s,
        rounds: plan.rounds,
        slowed_spans: plan.slowed_spans,
        moves: layout.moves.len(),
        spans: layout.spans.len(),
        pierces,
        cut_length_mm: cut,
        rapid_length_mm: rapid,
        laser_on_s: ex.iter().filter(|e| e.laser_on).count() as f64 * dt,
        samples: n,
        sample_period_s: dt,
        planner_s: planned.planner_s,
        execution_s: r.execution_s,
        micro_stage: r.stage.to_string(),
    }
}

/// The executed trajectories as CSV (every `every`-th sample): time, beam, the tool planned
/// and executed, the gantry's reference and position, the micro's planned and executed offset
/// from its workspace centre, the contour error (empty with the beam off).
pub fn executed_csv(
    spec: &MachineSpec,
    program: &str,
    planned: &Planned,
    executed: &[Executed],
    every: usize,
) -> String {
    use std::fmt::Write as _;
    let plan = &planned.plan;
    let errs = contour_errors_um(planned, executed);
    let mut s = String::with_capacity(executed.len() / every.max(1) * 150 + 512);
    let _ = writeln!(
        s,
        "# machine={} digest={} program={} sample_period_s={} decimation={} plan={}",
        spec.name,
        MachineId::of(spec).digest,
        program,
        plan.dt_s,
        every.max(1),
        match plan.mode {
            PlanMode::Split => "split",
            PlanMode::GantryOnly => "gantry-only",
        }
    );
    s.push_str(
        "t_s,laser,tool_x_mm,tool_y_mm,tool_exec_x_mm,tool_exec_y_mm,gantry_ref_x_mm,gantry_ref_y_mm,\
         gantry_x_mm,gantry_y_mm,micro_ref_x_mm,micro_ref_y_mm,micro_x_mm,micro_y_mm,contour_err_um\n",
    );
    for (k, e) in executed.iter().enumerate().step_by(every.max(1)) {
        let (p, g, q) = (plan.tool_mm[k], plan.gantry_mm[k], e.tool_mm());
        let _ = write!(
            s,
            "{:.4},{},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},",
            k as f64 * plan.dt_s,
            u8::from(e.laser_on),
            p[0],
            p[1],
            q[0],
            q[1],
            g[0],
            g[1],
            e.gantry_mm[0],
            e.gantry_mm[1],
            p[0] - g[0],
            p[1] - g[1],
            e.micro_mm[0],
            e.micro_mm[1],
        );
        if let Some(c) = errs[k] {
            let _ = write!(s, "{c:.3}");
        }
        s.push('\n');
    }
    s
}
