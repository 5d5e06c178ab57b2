//! Trajectory durations against the reference Ruckig, side by side, on the same moves and
//! limits: `cargo bench -p host-sim --bench trajectory`.
//!
//! The core's planner (`kinematics_core::jerk_profile`, `trajectory`) is closed-form and
//! time-optimal for rest-to-rest moves; Ruckig (pip package `ruckig`, the reference
//! implementation of Berscheid & Kröger's jerk-limited real-time trajectory generation) solves
//! the general problem numerically. Same moves, same limits:
//! * one axis: the distance with the speed, acceleration and jerk limits;
//! * a straight move in the plane: our limits are on the *norm* of the tool's speed,
//!   acceleration and jerk; Ruckig's are per axis, so it gets `limit·|u_i|` on axis i with
//!   phase synchronisation (every axis in step): the same straight-line problem.
//!
//! Prints each move's durations and the ratio `Ruckig / ours` (≥ 0.98 required: ours at most
//! 2 % slower than Ruckig's optimum; 1.000 means equal). Needs Python 3; if the `ruckig`
//! package is not importable, it is installed with pip into a virtual environment under
//! `target/ruckig-venv` (a reference for this benchmark only, never the product's).

use kinematics_core::trajectory::{PathMotion, TaskLimits};
use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};

const G: f64 = 9_806.65;

/// A Python with `ruckig` importable: the system's, or a virtual environment made for it.
fn python_with_ruckig() -> Result<PathBuf, String> {
    let works = |py: &PathBuf| {
        Command::new(py)
            .args(["-c", "import ruckig"])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    let system = PathBuf::from("python3");
    if works(&system) {
        return Ok(system);
    }
    let venv = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/ruckig-venv");
    let py = venv.join("bin/python");
    if !works(&py) {
        eprintln!(
            "installing the reference `ruckig` into {} (pip) ...",
            venv.display()
        );
        let made = Command::new("python3")
            .arg("-m")
            .arg("venv")
            .arg(&venv)
            .status()
            .map_err(|e| format!("python3: {e}"))?;
        if !made.success() {
            return Err("python3 -m venv failed (Debian: apt-get install python3-venv)".into());
        }
        let pip = Command::new(&py)
            .args(["-m", "pip", "install", "--quiet", "ruckig"])
            .status()
            .map_err(|e| format!("pip: {e}"))?;
        if !pip.success() || !works(&py) {
            return Err("pip install ruckig failed (no network?)".into());
        }
    }
    Ok(py)
}

struct Case {
    name: String,
    from: Vec<f64>,
    to: Vec<f64>,
    limits: TaskLimits<f64>,
}

fn main() {
    let limit_sets = [
        (
            "5 g, 1.5 m/s, 5e6 mm/s³",
            TaskLimits {
                speed_mm_s: 1500.0,
                accel_mm_s2: 5.0 * G,
                jerk_mm_s3: 5e6,
            },
        ),
        (
            "2 g, 1.5 m/s, 2e6 mm/s³",
            TaskLimits {
                speed_mm_s: 1500.0,
                accel_mm_s2: 2.0 * G,
                jerk_mm_s3: 2e6,
            },
        ),
        (
            "5 g, 0.5 m/s, 2e7 mm/s³",
            TaskLimits {
                speed_mm_s: 500.0,
                accel_mm_s2: 5.0 * G,
                jerk_mm_s3: 2e7,
            },
        ),
    ];
    let mut cases = Vec::new();
    for (label, limits) in &limit_sets {
        for d in [0.01, 0.5, 2.0, 10.0, 25.0, 50.0, 100.0, 180.0] {
            cases.push(Case {
                name: format!("1 axis {d:>6} mm, {label}"),
                from: vec![0.0],
                to: vec![d],
                limits: *limits,
            });
        }
        for (a, b) in [
            ([212.132, 0.0], [222.132, 0.0]),
            ([172.132, -65.0], [252.132, 65.0]),
            ([250.0, 60.0], [180.0, 55.0]),
            ([200.0, -70.0], [203.0, 70.0]),
        ] {
            let name = format!(
                "line ({:.0},{:.0})→({:.0},{:.0}), {label}",
                a[0], a[1], b[0], b[1]
            );
            cases.push(Case {
                name,
                from: a.to_vec(),
                to: b.to_vec(),
                limits: *limits,
            });
        }
    }
    // Ours.
    let ours: Vec<f64> = cases
        .iter()
        .map(|c| {
            let (from, to) = if c.from.len() == 1 {
                ([0.0, 0.0], [c.to[0], 0.0])
            } else {
                ([c.from[0], c.from[1]], [c.to[0], c.to[1]])
            };
            PathMotion::line(from, to, &c.limits)
                .expect("plannable")
                .duration_s()
        })
        .collect();
    // Ruckig's, with per-axis limits scaled by the direction cosines (same straight line).
    let moves: Vec<serde_json::Value> = cases
        .iter()
        .map(|c| {
            let d: Vec<f64> = c.to.iter().zip(&c.from).map(|(t, f)| t - f).collect();
            let n = d.iter().map(|x| x * x).sum::<f64>().sqrt();
            let share = |limit: f64| {
                d.iter()
                    .map(|x| (limit * x.abs() / n).max(1e-9 * limit))
                    .collect::<Vec<_>>()
            };
            serde_json::json!({
                "from": c.from, "to": c.to,
                "velocity": share(c.limits.speed_mm_s),
                "acceleration": share(c.limits.accel_mm_s2),
                "jerk": share(c.limits.jerk_mm_s3),
            })
        })
        .collect();
    let py = match python_with_ruckig() {
        Ok(p) => p,
        Err(e) => {
            eprintln!("trajectory bench: cannot run the reference Ruckig: {e}");
            std::process::exit(1);
        }
    };
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/ruckig_reference.py");
    let mut child = Command::new(&py)
        .arg(&script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("python runs");
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(serde_json::to_string(&moves).expect("json").as_bytes())
        .expect("write moves");
    let out = child.wait_with_output().expect("ruckig finishes");
    if !out.status.success() {
        eprintln!("trajectory bench: the reference Ruckig failed");
        std::process::exit(1);
    }
    let reference: Vec<f64> = serde_json::from_slice(&out.stdout).expect("durations");
    println!(
        "{:<58} {:>12} {:>12} {:>8}",
        "move, limits", "ours (ms)", "Ruckig (ms)", "ratio"
    );
    let mut worst: f64 = f64::INFINITY;
    for ((c, o), r) in cases.iter().zip(&ours).zip(&reference) {
        let ratio = r / o;
        worst = worst.min(ratio);
        println!(
            "{:<58} {:>12.4} {:>12.4} {:>8.5}",
            c.name,
            o * 1e3,
            r * 1e3,
            ratio
        );
    }
    println!("TRAJECTORY ruckig_duration_ratio_min {worst:.5} over {} moves (>= 0.98 required; 1 = Ruckig's optimum)", cases.len());
    // NaN (a failed comparison) fails too.
    if worst.is_nan() || worst < 0.98 {
        std::process::exit(1);
    }
}
