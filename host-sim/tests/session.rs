//! A measurement session through a controller (`host_sim::session`), on the in-process rig
//! (the simulated plant behind a controller that commands as the firmware does): the plan's
//! lists visited with their approach give what `measure` gives for the same plant and noise,
//! the grid list keeps its nodes, and bad input stops the session with a clear error before or
//! at the point it concerns (a list the machine cannot visit: nothing moves).

use host_sim::calib::fit::evaluate::Criterion;
use host_sim::calib::fit::{fit, FitOptions, FrameMode, Method, Points};
use host_sim::calib::machine::{Machine, PlantMachine};
use host_sim::calib::measure::{measure_list, rows};
use host_sim::calib::plan::{plan, PlanOptions};
use host_sim::calib::protocol::Visit;
use host_sim::machine_spec::MachineSpec;
use host_sim::session::fake::FakeRig;
use host_sim::session::{run, SessionError, SessionOptions};
use kinematics_core::Calibration;

fn rig(spec: &MachineSpec, seed: u64) -> FakeRig {
    let mut m = PlantMachine::by_name("paper", Some(1.0), seed).unwrap();
    m.reseed(seed);
    FakeRig::new(m, spec.nominal, None, spec.min_transmission)
}

fn full_fit(data: &[host_sim::io::measurement_csv::Measurement], spec: &MachineSpec) -> [f64; 4] {
    let o = fit(
        data,
        &FitOptions {
            method: Method::Full,
            criterion: Criterion::Measured,
            points: Points::All,
            fixed: vec![],
            leave_one_out: false,
            reject_sigma: 4.0,
            frame: FrameMode::Register,
            spec: spec.clone(),
        },
        &mut |_| {},
    )
    .unwrap();
    [o.model.a_mm, o.model.b_mm, o.model.c_mm, o.model.d_mm]
}

/// The identification list through the session reads what `measure` reads on the same plant
/// with the same noise (the approach point makes each motor arrive as the list says), except
/// the rows moved inside the soft limit; the fits agree to a nanometre.
#[test]
fn a_session_measures_what_measure_measures() {
    let spec = MachineSpec::paper();
    let p = plan(&PlanOptions::new(spec.clone(), 1)).unwrap();
    let mut r = rig(&spec, 11);
    let got = run(
        &mut r,
        &p.identify,
        &SessionOptions::for_machine(&spec),
        &mut |_, _| {},
    )
    .unwrap();
    let nominal = Calibration {
        model: spec.nominal.cast(),
        grid: None,
    };
    let mut m = PlantMachine::by_name("paper", Some(1.0), 11).unwrap();
    let want =
        rows(&measure_list(&mut m, &nominal, &p.identify, spec.approach, 11, &spec).unwrap());
    let rep = &got.report;
    eprintln!("{rep:?}");
    assert_eq!((rep.points, rep.read), (40, 40));
    assert!(!rep.grid_list && rep.missing.is_empty());
    let moved: Vec<&str> = rep.moved_in.iter().map(|(id, _)| id.as_str()).collect();
    for (k, (a, b)) in got.measurements.iter().zip(&want).enumerate() {
        if moved.contains(&format!("P{:03}", k + 1).as_str()) {
            continue;
        }
        assert_eq!(a.target_mm, b.target_mm, "row {k}");
        assert_eq!(a.dir, b.dir, "row {k}");
        for j in 0..2 {
            assert!((a.theta_deg[j] - b.theta_deg[j]).abs() < 1e-9, "row {k}");
            assert!(
                (a.measured_mm[j] - b.measured_mm[j]).abs() < 1e-9,
                "row {k}"
            );
        }
    }
    assert!(rep.settle_s_max > 0.0 && rep.settle_s_max < 1.0, "{rep:?}");
    assert!(rep.following_error_urad_max <= 2.0, "{rep:?}");
    // The fits on the rows both read at the same place agree.
    let same = |d: &[host_sim::io::measurement_csv::Measurement]| -> Vec<_> {
        d.iter()
            .enumerate()
            .filter(|(k, _)| !moved.contains(&format!("P{:03}", k + 1).as_str()))
            .map(|(_, m)| m.clone())
            .collect()
    };
    let (a, b) = (
        full_fit(&same(&got.measurements), &spec),
        full_fit(&same(&want), &spec),
    );
    for k in 0..4 {
        assert!((a[k] - b[k]).abs() < 1e-6, "{a:?} {b:?}");
    }
}

/// The grid list: every node's target is the node (the grid refers a reading taken just inside
/// the soft limit to it), the edge nodes are moved in by the inset and no further.
#[test]
fn the_grid_list_keeps_its_nodes() {
    let spec = MachineSpec::paper();
    let p = plan(&PlanOptions::new(spec.clone(), 1)).unwrap();
    let o = SessionOptions::for_machine(&spec);
    let got = run(&mut rig(&spec, 15), &p.grid, &o, &mut |_, _| {}).unwrap();
    assert!(got.report.grid_list);
    assert_eq!(got.measurements.len(), 21 * 31);
    for (m, v) in got.measurements.iter().zip(&p.grid) {
        assert_eq!(m.target_mm, Some(v.target_mm));
    }
    // The rectangle's edge nodes (80 of 651) are moved in; none by more than 1 mm.
    let n = got.report.moved_in.len();
    assert!((80..=100).contains(&n), "{n} moved in");
    assert!(got
        .report
        .moved_in
        .iter()
        .all(|(_, d)| *d <= 1.0 && *d >= o.edge_inset_mm));
}

/// Bad input: a list the machine cannot visit (nothing moves), a controller that is not homed
/// (nothing moves), a link that drops, a servo that does not settle, a reading not seen (noted)
/// or absurd (refused), each naming the point.
#[test]
fn bad_input_stops_the_session_clearly() {
    let spec = MachineSpec::paper();
    let p = plan(&PlanOptions::new(spec.clone(), 1)).unwrap();
    let o = SessionOptions::for_machine(&spec);
    let list: Vec<Visit> = p.verify[..12].to_vec();
    // A target outside the workspace in row 5: refused before anything moves.
    let mut bad = list.clone();
    bad[4].target_mm = [300.0, 0.0];
    let mut r = rig(&spec, 1);
    let e = run(&mut r, &bad, &o, &mut |_, _| {}).unwrap_err();
    assert!(matches!(e, SessionError::Plan { row: 5, .. }), "{e}");
    assert!(
        e.to_string()
            .contains("outside machine 'paper''s workspace"),
        "{e}"
    );
    assert_eq!(r.moves, 0);
    let mut r = rig(&spec, 1);
    r.faults.unhomed = true;
    let e = run(&mut r, &list, &o, &mut |_, _| {}).unwrap_err();
    assert!(e.to_string().contains("home it first"), "{e}");
    assert_eq!(r.moves, 0);
    // The link drops at the 7th move (row 4's approach).
    let mut r = rig(&spec, 1);
    r.faults.drop_at_move = Some(6);
    let e = run(&mut r, &list, &o, &mut |_, _| {}).unwrap_err();
    assert!(
        matches!(&e, SessionError::Point { point, .. } if point == "P004"),
        "{e}"
    );
    let mut r = rig(&spec, 1);
    r.faults.hunting = true;
    let e = run(&mut r, &list, &o, &mut |_, _| {}).unwrap_err();
    assert!(e.to_string().contains("did not settle"), "{e}");
    // Not seen: noted, the row left out.
    let mut r = rig(&spec, 1);
    r.faults.missing = vec![2, 7];
    let got = run(&mut r, &list, &o, &mut |_, _| {}).unwrap();
    assert_eq!(got.report.missing, ["P003", "P008"]);
    assert_eq!(got.measurements.len(), 10);
    assert_eq!(got.commanded.len(), 12);
    // Absurd: 20 mm off where the others put it.
    let mut r = rig(&spec, 1);
    let t = list[8].target_mm;
    r.faults.absurd = Some((8, [t[0] + 20.0, t[1] - 3.0]));
    let e = run(&mut r, &list, &o, &mut |_, _| {}).unwrap_err();
    assert!(
        matches!(&e, SessionError::Reading { point, .. } if point == "P009"),
        "{e}"
    );
    let mut r = rig(&spec, 1);
    r.faults.absurd = Some((3, [f64::NAN, 1.0]));
    let e = run(&mut r, &list, &o, &mut |_, _| {}).unwrap_err();
    assert!(
        e.to_string().contains("P004") && e.to_string().contains("not a position"),
        "{e}"
    );
}

/// `host-sim session` refuses what makes no session, and a controller that does not answer
/// (nothing listening; a listener that never replies) is a clear error with no file written.
#[test]
fn the_command_refuses_a_silent_controller_and_bad_flags() {
    use std::process::Command;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let list = d.join("t.csv");
    std::fs::write(&list, "x_mm,y_mm\n212.132,0\n220,10\n").unwrap();
    let out = d.join("m.csv");
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .arg("session")
            .args(args)
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let (l, o) = (list.to_str().unwrap(), out.to_str().unwrap());
    let (ok, e) = run(&["--tcp", "127.0.0.1:1", "--targets", l]);
    assert!(!ok && e.contains("give --out FILE"), "{e}");
    let (ok, e) = run(&[
        "--tcp",
        "127.0.0.1:1",
        "--targets",
        l,
        "--instrument",
        "export",
    ]);
    assert!(!ok && e.contains("--angles-out"), "{e}");
    // Nothing listening.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let addr = format!("127.0.0.1:{port}");
    let (ok, e) = run(&[
        "--tcp",
        &addr,
        "--timeout-s",
        "0.5",
        "--targets",
        l,
        "--out",
        o,
    ]);
    assert!(!ok && e.contains("connecting to"), "{e}");
    assert!(!out.exists());
    // A listener that never replies.
    let silent = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = format!("127.0.0.1:{}", silent.local_addr().unwrap().port());
    let keep = std::thread::spawn(move || {
        let (mut s, _) = silent.accept().unwrap();
        let mut buf = [0u8; 256];
        while std::io::Read::read(&mut s, &mut buf).is_ok_and(|n| n > 0) {}
    });
    let (ok, e) = run(&[
        "--tcp",
        &addr,
        "--timeout-s",
        "0.5",
        "--targets",
        l,
        "--out",
        o,
    ]);
    assert!(!ok && e.contains("no reply from the controller"), "{e}");
    assert!(e.contains("nothing written"), "{e}");
    assert!(!out.exists());
    drop(keep);
}
