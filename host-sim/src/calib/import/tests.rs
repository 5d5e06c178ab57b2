use super::*;
use crate::io::commanded_csv::parse_commanded;
use crate::io::targets_csv::parse_target_list;
use crate::io::tracker_export::{parse_export, ColumnMap};

/// A list of `n` targets on a 10 mm lattice, commanded with made-up angles (row k: k°, 2k°).
fn list(n: usize) -> Vec<CommandedRow> {
    let mut text = String::from("x_mm,y_mm,theta1_deg,theta2_deg\n");
    for k in 1..=n {
        text.push_str(&format!(
            "{},{},{k},{}\n",
            180 + 10 * (k % 5),
            -40 + 10 * (k / 5) as i64,
            2 * k
        ));
    }
    parse_commanded(&text).unwrap()
}

/// An export of the given (id, x, y, z) rows: the targets shifted by (1, 2) mm.
fn export(rows: &[(&str, usize)], z: impl Fn(usize) -> f64) -> Export {
    let mut text = String::from("Point;X;Y;Z\n");
    for &(id, k) in rows {
        text.push_str(&format!(
            "{id};{};{};{}\n",
            181 + 10 * (k % 5),
            -38 + 10 * (k / 5) as i64,
            z(k)
        ));
    }
    parse_export(
        &text,
        &ColumnMap::parse("id=Point,x=X,y=Y,z=Z").unwrap(),
        None,
    )
    .unwrap()
}

#[test]
fn ids_join_rows_with_repeats_missing_and_notes() {
    let e = export(
        &[("P003", 3), ("P001", 1), ("P003", 3), ("P004", 4)],
        |_| 5.0,
    );
    let got = import(&e, &list(4), None, &ImportOptions::default()).unwrap();
    // List order; the repeated point's readings as runs 0 and 1.
    let keys: Vec<([f64; 2], Option<u32>)> =
        got.rows.iter().map(|m| (m.theta_deg, m.run)).collect();
    assert_eq!(
        keys,
        vec![
            ([1.0, 2.0], Some(0)),
            ([3.0, 6.0], Some(0)),
            ([3.0, 6.0], Some(1)),
            ([4.0, 8.0], Some(0))
        ]
    );
    assert_eq!(got.rows[0].measured_mm, [191.0, -38.0]);
    assert_eq!(got.rows[0].target_mm, Some([190.0, -40.0]));
    let r = &got.report;
    assert_eq!(
        (
            r.missing.clone(),
            r.repeated.clone(),
            r.imported,
            r.rows_measured
        ),
        (vec![2], vec![3], 4, 3)
    );
    assert_eq!(r.id_prefix, "P");
    assert!(
        r.notes
            .iter()
            .any(|n| n.contains("have no reading (not written): points 2")),
        "{:?}",
        r.notes
    );
    let f = r.frame.as_ref().unwrap();
    assert!(
        (f.scale - 1.0).abs() < 1e-12 && f.rigid_residual_max_mm < 1e-9,
        "{f:?}"
    );
    assert!(r.warnings.is_empty(), "{:?}", r.warnings);
    // The same export with --require-all: an error naming the point.
    let opts = ImportOptions {
        missing: Missing::Refuse,
        ..Default::default()
    };
    assert_eq!(
        import(&e, &list(4), None, &opts).unwrap_err(),
        ImportError::Missing {
            numbers: vec![2],
            rows: 4
        }
    );
}

#[test]
fn numbering_prefixes_and_unlisted_points() {
    let e = export(&[("P0", 0), ("P1", 1), ("P2", 2)], |_| 0.0);
    // Counting from 0 needs --first-id 0.
    assert!(matches!(
        import(&e, &list(3), None, &ImportOptions::default()).unwrap_err(),
        ImportError::Unlisted {
            number: 0,
            line: 2,
            ..
        }
    ));
    let opts = ImportOptions {
        first_id: 0,
        ..Default::default()
    };
    let got = import(&e, &list(3), None, &opts).unwrap();
    assert_eq!(got.rows[0].theta_deg, [1.0, 2.0]);
    // A point beyond the list: an error, or skipped with a note.
    let e = export(&[("P1", 1), ("P2", 2), ("P9", 3)], |_| 0.0);
    let err = import(&e, &list(3), None, &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("line 4: point 'P9' is number 9, but the list's rows are numbers 1..=3"),
        "{err}"
    );
    let got = import(
        &e,
        &list(3),
        None,
        &ImportOptions {
            unlisted: Unlisted::Skip,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(got.report.skipped, vec!["P9".to_string()]);
    // Reference points with another prefix: refused without --id-prefix, skipped with it.
    let e = export(&[("BASE1", 1), ("P1", 1), ("P2", 2), ("P3", 3)], |_| 0.0);
    let err = import(&e, &list(3), None, &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(&err, ImportError::MixedPrefixes { first, other, .. } if first == "BASE" && other == "P"),
        "{err}"
    );
    let got = import(
        &e,
        &list(3),
        None,
        &ImportOptions {
            id_prefix: Some("P".into()),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        (got.report.skipped.clone(), got.rows.len()),
        (vec!["BASE1".to_string()], 3)
    );
    // An id without a number.
    let e = export(&[("P1", 1), ("Home", 2)], |_| 0.0);
    assert!(import(&e, &list(3), None, &ImportOptions::default())
        .unwrap_err()
        .to_string()
        .contains("point id 'Home' ends in no number"));
}

#[test]
fn z_spread_tolerance_and_tilt() {
    let ids: Vec<(String, usize)> = (1..=10).map(|k| (format!("P{k}"), k)).collect();
    let rows: Vec<(&str, usize)> = ids.iter().map(|(s, k)| (s.as_str(), *k)).collect();
    // A plane tilted 10 mrad along x (dz/dx = tan 10 mrad), one point 0.05 mm off it.
    let z = |k: usize| {
        (181.0 + 10.0 * (k % 5) as f64) * 0.01f64.tan() + if k == 7 { 0.05 } else { 0.0 }
    };
    let got = import(
        &export(&rows, z),
        &list(10),
        None,
        &ImportOptions::default(),
    )
    .unwrap();
    let zr = got.report.z.as_ref().unwrap();
    assert_eq!(zr.points, 10);
    assert!((zr.tilt_mrad - 10.0).abs() < 0.5, "{zr:?}");
    assert!(
        zr.plane_residual_max_um > 35.0 && zr.plane_residual_max_um < 50.0,
        "{zr:?}"
    );
    assert!(
        got.report.warnings.iter().any(|w| w.contains("tilted")),
        "{:?}",
        got.report.warnings
    );
    let opts = ImportOptions {
        z_tolerance_mm: Some(0.02),
        ..Default::default()
    };
    let err = import(&export(&rows, z), &list(10), None, &opts).unwrap_err();
    assert!(
        matches!(&err, ImportError::ZTolerance { id, line: 8, .. } if id == "P7"),
        "{err}"
    );
    // A level plane: no warning.
    let got = import(
        &export(&rows, |_| 3.0),
        &list(10),
        None,
        &ImportOptions::default(),
    )
    .unwrap();
    assert!(got.report.warnings.is_empty() && got.report.z.as_ref().unwrap().tilt_mrad == 0.0);
}

#[test]
fn units_mirror_and_numbering_mistakes() {
    let rows: Vec<(String, usize)> = (1..=10).map(|k| (format!("P{k}"), k)).collect();
    let text = |f: &dyn Fn(usize) -> (f64, f64)| {
        let mut t = String::from("Point,X,Y\n");
        for (id, k) in &rows {
            let (x, y) = f(*k);
            t.push_str(&format!("{id},{x},{y}\n"));
        }
        parse_export(&t, &ColumnMap::parse("id=Point,x=X,y=Y").unwrap(), None).unwrap()
    };
    let target = |k: usize| {
        (
            (180 + 10 * (k % 5)) as f64,
            (-40 + 10 * (k / 5) as i64) as f64,
        )
    };
    // Metres read as mm.
    let err = import(
        &text(&|k| (target(k).0 / 1e3, target(k).1 / 1e3)),
        &list(10),
        None,
        &ImportOptions::default(),
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("looks like metres read as mm"),
        "{err}"
    );
    // Seen from the other side of the plane.
    let err = import(
        &text(&|k| (target(k).0, -target(k).1)),
        &list(10),
        None,
        &ImportOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(err, ImportError::Mirrored { .. }), "{err}");
    // Numbered one row off: a warning with the figure.
    let got = import(
        &text(&|k| target(k - 1 + (k == 1) as usize * 10)),
        &list(10),
        None,
        &ImportOptions::default(),
    )
    .unwrap();
    assert!(
        got.report
            .warnings
            .iter()
            .any(|w| w.contains("check the numbering")),
        "{:?}",
        got.report
    );
}

#[test]
fn the_plan_list_brings_runs_and_a_repeat_list_refuses_a_second_reading() {
    let plan = parse_target_list(
        "x_mm,y_mm,dir1,dir2,run\n190,-40,1,1,0\n200,-40,1,1,0\n190,-40,-1,-1,1\n",
    )
    .unwrap();
    let commanded =
        parse_commanded("x_mm,y_mm,theta1_deg,theta2_deg\n190,-40,1,2\n200,-40,2,4\n190,-40,1,2\n")
            .unwrap();
    let e = export(&[("P1", 1), ("P2", 2), ("P3", 1)], |_| 0.0);
    let got = import(&e, &commanded, Some(&plan), &ImportOptions::default()).unwrap();
    assert_eq!(
        got.rows.iter().map(|m| (m.run, m.dir)).collect::<Vec<_>>(),
        vec![
            (Some(0), Some([1, 1])),
            (Some(0), Some([1, 1])),
            (Some(1), Some([-1, -1]))
        ]
    );
    let e = export(&[("P1", 1), ("P2", 2), ("P3", 1), ("P1", 1)], |_| 0.0);
    assert!(matches!(
        import(&e, &commanded, Some(&plan), &ImportOptions::default()).unwrap_err(),
        ImportError::RepeatedInRunList {
            line: 5,
            max_run: 1,
            ..
        }
    ));
    // A plan that is not the commanded list's.
    let other = parse_target_list("x_mm,y_mm\n190,-40\n210,-40\n190,-40\n").unwrap();
    let err = import(&e, &commanded, Some(&other), &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("row 2 (plan line 3, commanded line 3): target (210, -40) against (200, -40)"),
        "{err}"
    );
}
