//! The commanded list: what the controller was told at each point of a measurement session, in
//! the order of the session. `host-sim command` writes it (`angles.csv`,
//! `calib::command::format_commands`); a log of the firmware's commands in the same columns
//! reads the same. `host-sim import` joins a tracker's export with it (`calib::import`).
//!
//! CSV (`,` `;` or tab, `#` comments, columns in any order; other columns are refused):
//!
//! | column | required | meaning |
//! |---|---|---|
//! | `theta1_deg`, `theta2_deg` | yes | the motor angles commanded (or the encoder readings), degrees |
//! | `x_mm`, `y_mm` | no (both or neither) | the target the angles were meant to reach |
//! | `dir1`, `dir2` | no (both or neither) | `+1`/`-1`: each motor's direction on arrival |
//! | `run` | no | repeat index |
//!
//! Row `k` (1-based, in file order; comments and the header not counted) is the session's
//! point `k`: the number a tracker's point id carries (`calib::import`, *Point ids*).

use super::csv_dialect::{self, Quantity};
use super::{read_text, IoError};
use std::path::Path;

/// One commanded point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandedRow {
    /// Line in the file (1-based, header = 1).
    pub line: usize,
    pub theta_deg: [f64; 2],
    pub target_mm: Option<[f64; 2]>,
    pub dir: Option<[i8; 2]>,
    pub run: Option<u32>,
}

const COLUMNS: [&str; 7] = [
    "theta1_deg",
    "theta2_deg",
    "x_mm",
    "y_mm",
    "dir1",
    "dir2",
    "run",
];

/// The commanded list as text (every column; the target, directions and run where known,
/// empty otherwise), angles to 1e-9°.
pub fn format_commanded(rows: &[CommandedRow]) -> String {
    let mut out = String::from("theta1_deg,theta2_deg,x_mm,y_mm,dir1,dir2,run\n");
    for r in rows {
        let t = r
            .target_mm
            .map_or(",".to_string(), |t| format!("{:.6},{:.6}", t[0], t[1]));
        let d = r
            .dir
            .map_or(",".to_string(), |d| format!("{},{}", d[0], d[1]));
        let run = r.run.map_or(String::new(), |v| v.to_string());
        out.push_str(&format!(
            "{:.9},{:.9},{t},{d},{run}\n",
            r.theta_deg[0], r.theta_deg[1]
        ));
    }
    out
}

/// Parses a commanded list (module doc).
pub fn parse_commanded(text: &str) -> Result<Vec<CommandedRow>, IoError> {
    let err = |m: String| IoError::Parse(m);
    let mut reader = csv_dialect::reader(text);
    let headers = reader
        .headers()
        .map_err(|e| err(format!("line 1: cannot read the header: {e}")))?
        .clone();
    if let Some(h) = headers.iter().find(|h| !COLUMNS.contains(h)) {
        return Err(err(format!("line 1: unknown column '{h}' (a commanded list has theta1_deg,theta2_deg and optionally x_mm,y_mm, dir1,dir2, run)")));
    }
    let at = |name: &str| headers.iter().position(|h| h == name);
    let (Some(i1), Some(i2)) = (at("theta1_deg"), at("theta2_deg")) else {
        return Err(err("line 1: required columns 'theta1_deg' and 'theta2_deg' (the commanded angles) are missing".into()));
    };
    let (target, dir, run) = (
        csv_dialect::column_pair(&headers, "x_mm", "y_mm")?,
        csv_dialect::column_pair(&headers, "dir1", "dir2")?,
        at("run"),
    );
    let mut out = Vec::new();
    for record in csv_dialect::records(&mut reader, headers.len()) {
        let (line, record) = record?;
        let num = |i: usize, q: Quantity| csv_dialect::number(&record[i], &headers[i], line, q);
        let sign = |i: usize| csv_dialect::direction(&record[i], &headers[i], line);
        out.push(CommandedRow {
            line,
            theta_deg: [num(i1, Quantity::AngleDeg)?, num(i2, Quantity::AngleDeg)?],
            target_mm: target
                .map(|(i, j)| {
                    Ok::<_, IoError>([num(i, Quantity::LengthMm)?, num(j, Quantity::LengthMm)?])
                })
                .transpose()?,
            dir: dir
                .map(|(i, j)| Ok::<_, IoError>([sign(i)?, sign(j)?]))
                .transpose()?,
            run: run
                .map(|i| csv_dialect::run_index(&record[i], line))
                .transpose()?,
        });
    }
    if out.is_empty() {
        return Err(err("no commanded points after the header".into()));
    }
    Ok(out)
}

/// Reads a commanded list.
pub fn read_commanded(path: &Path) -> Result<Vec<CommandedRow>, IoError> {
    parse_commanded(&read_text(path)?).map_err(|e| IoError::content(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn what_command_writes_reads_back() {
        let rows = parse_commanded("x_mm,y_mm,theta1_deg,theta2_deg,dir1,dir2\n212.132,0,45.000000000,135.000000000,1,-1\n200,-5,50,140,-1,1\n").unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(
            rows[0],
            CommandedRow {
                line: 2,
                theta_deg: [45.0, 135.0],
                target_mm: Some([212.132, 0.0]),
                dir: Some([1, -1]),
                run: None
            }
        );
        assert_eq!(rows[1].line, 3);
        let bare = parse_commanded("theta2_deg;theta1_deg;run\n1;2;3\n").unwrap();
        assert_eq!(
            bare[0],
            CommandedRow {
                line: 2,
                theta_deg: [2.0, 1.0],
                target_mm: None,
                dir: None,
                run: Some(3)
            }
        );
    }

    #[test]
    fn errors() {
        for (text, want) in [
            ("x_mm,y_mm\n1,2\n", "'theta1_deg' and 'theta2_deg'"),
            (
                "theta1_deg,theta2_deg,x_mm\n1,2,3\n",
                "'x_mm' and 'y_mm' come together",
            ),
            ("theta1_deg,theta2_deg,z\n1,2,3\n", "unknown column 'z'"),
            (
                "theta1_deg,theta2_deg\n1,nan\n",
                "line 2: 'theta2_deg' = 'nan' is not finite",
            ),
            (
                "theta1_deg,theta2_deg,dir1,dir2\n1,2,1,0\n",
                "line 2: 'dir2' = '0' is not +1 or -1",
            ),
            ("theta1_deg,theta2_deg\n", "no commanded points"),
        ] {
            let e = parse_commanded(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }
}
