//! The measurement CSV: the contract between measuring (a real interferometer or `host-sim
//! measure`; a laser tracker's export through `host-sim import`, `calib::import`) and every tool
//! that reads measurements (`fit`, `grid`, `diagnose`, `accuracy`).
//!
//! An optional first line `# machine=NAME digest=HEX8` names the machine the measurements are
//! of (`crate::machine_identity`; every file the tools write has it, files without it are read
//! with a note). Then a header line, comma separated (`;` and tab are read too: the delimiter is detected from the
//! header, see [`super::csv_dialect`]), columns in any order:
//!
//! | column | required | meaning |
//! |---|---|---|
//! | `theta1_deg`, `theta2_deg` | yes | motor angles commanded (encoder readings), degrees; any value (368° is fine) |
//! | `x_mm`, `y_mm` | yes | measured tool point, instrument frame |
//! | `x_target_mm`, `y_target_mm` | no (both or neither) | where the angles were meant to put the tool |
//! | `dir1`, `dir2` | no (both or neither) | `+1`/`-1`: sign of each motor's last motion before the measurement |
//! | `run` | no | repeat index (0, 1, ...) |
//! | `t_s` | no | time of the measurement (s) |
//!
//! Unknown columns are refused by default (a misspelt optional column would otherwise be silently
//! lost); [`ExtraColumns::Ignore`] reads files that carry more (an instrument's export with its
//! own columns): the unknown columns are skipped and named in a note, but one that looks like a
//! known column (the same name but for case, spaces or a missing unit, e.g. `X_target`,
//! `theta1`) is still refused. Every number must be finite and within the range of its quantity
//! (`csv_dialect`: |angle| ≤ 1e6°, |length| ≤ 1e6 mm). Errors name the line (1-based, the header
//! is line 1) and column.

use super::atomic::write_atomic;
use super::csv_dialect::{self, Quantity};
use super::{read_text, IoError};
use crate::machine_identity::{self, MachineIdentity};
use std::path::Path;

/// A format error: the message names the line and column.
macro_rules! bail {
    ($($t:tt)*) => { return Err(IoError::Parse(format!($($t)*))) };
}

/// One measured pose.
#[derive(Clone, Debug, PartialEq)]
pub struct Measurement {
    /// Motor angles commanded (encoder readings), degrees as in the file.
    pub theta_deg: [f64; 2],
    /// Measured tool point (mm, instrument frame).
    pub measured_mm: [f64; 2],
    /// Where the angles were meant to put the tool, if known.
    pub target_mm: Option<[f64; 2]>,
    /// Approach direction of each motor (+1/-1), if known.
    pub dir: Option<[i8; 2]>,
    /// Repeat index, if the file has one.
    pub run: Option<u32>,
    /// Time of the measurement (s), if the file has one.
    pub t_s: Option<f64>,
    /// Line in the file (1-based; 0 for data not read from a file).
    pub line: usize,
}

impl Measurement {
    /// Motor angles in radians (what the kinematics take).
    pub fn theta_rad(&self) -> [f64; 2] {
        [
            self.theta_deg[0].to_radians(),
            self.theta_deg[1].to_radians(),
        ]
    }
}

const COLUMNS: [&str; 10] = [
    "theta1_deg",
    "theta2_deg",
    "x_mm",
    "y_mm",
    "x_target_mm",
    "y_target_mm",
    "dir1",
    "dir2",
    "run",
    "t_s",
];

/// The quantity of each column, for its range check.
const QUANTITIES: [Quantity; 10] = [
    Quantity::AngleDeg,
    Quantity::AngleDeg,
    Quantity::LengthMm,
    Quantity::LengthMm,
    Quantity::LengthMm,
    Quantity::LengthMm,
    Quantity::Plain,
    Quantity::Plain,
    Quantity::Plain,
    Quantity::TimeS,
];

/// What to do with columns the format does not know.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExtraColumns {
    /// Refuse the file (the default: a misspelt column would be lost).
    #[default]
    Refuse,
    /// Skip them, with a note; a column that looks like a known one is still refused.
    Ignore,
}

/// How to read a measurement file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReadOptions {
    pub extra_columns: ExtraColumns,
}

/// Measurements and what the reader noticed (skipped columns, the delimiter when not a comma).
#[derive(Clone, Debug, PartialEq)]
pub struct ReadMeasurements {
    pub rows: Vec<Measurement>,
    pub notes: Vec<String>,
    /// The machine the measurements are of (the `# machine=NAME digest=HEX8` line), if given.
    pub machine: Option<MachineIdentity>,
}

/// Reads a measurement file with the machine it names.
pub fn read_measurement_file(path: &Path) -> Result<ReadMeasurements, IoError> {
    read_measurements_with(path, &ReadOptions::default())
}

/// Reads and validates a measurement file.
pub fn read_measurements(path: &Path) -> Result<Vec<Measurement>, IoError> {
    parse_measurements(&read_text(path)?).map_err(|e| IoError::content(path, e))
}

/// Reads a measurement file with options.
pub fn read_measurements_with(
    path: &Path,
    opts: &ReadOptions,
) -> Result<ReadMeasurements, IoError> {
    parse_measurements_with(&read_text(path)?, opts).map_err(|e| IoError::content(path, e))
}

/// Parses measurement CSV text (see the module doc for the format).
pub fn parse_measurements(text: &str) -> Result<Vec<Measurement>, IoError> {
    parse_measurements_with(text, &ReadOptions::default()).map(|r| r.rows)
}

/// A column name reduced to what a person would consider the same: lower case, no spaces,
/// dashes or underscores, and no unit suffix.
fn loose(name: &str) -> String {
    let mut s: String = name
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric())
        .collect();
    for unit in ["deg", "mm", "s"] {
        if let Some(stem) = s.strip_suffix(unit) {
            if !stem.is_empty() {
                s = stem.to_string();
                break;
            }
        }
    }
    s
}

/// Parses measurement CSV text with options.
pub fn parse_measurements_with(
    text: &str,
    opts: &ReadOptions,
) -> Result<ReadMeasurements, IoError> {
    // The machine line, among the comment lines before the header.
    let machine = text
        .lines()
        .map(str::trim)
        .take_while(|l| l.is_empty() || l.starts_with('#'))
        .find_map(machine_identity::parse_csv_line);
    let mut reader = csv_dialect::reader(text);
    let headers = match reader.headers() {
        Ok(h) => h.clone(),
        Err(e) => bail!("line 1: cannot read the header: {e}"),
    };
    let mut notes = Vec::new();
    let delimiter = csv_dialect::detect_delimiter(text);
    if delimiter != b',' {
        notes.push(format!(
            "{}-separated file",
            csv_dialect::delimiter_name(delimiter)
        ));
    }
    // A target list given where measurements are wanted: say what it is and what to do.
    let has = |c: &str| headers.iter().any(|h| h == c);
    if has("x_mm") && has("y_mm") && !has("theta1_deg") && !has("theta2_deg") {
        let what = if has("from_x_mm") || has("dir1") || has("run") {
            "a plan's target list"
        } else {
            "a target list"
        };
        bail!("line 1: this is {what} (x_mm,y_mm and no motor angles), not measurements: measure it first (`host-sim measure --targets FILE` on a simulated machine; on a real one `command`, the session, then `import`) and give the measurement CSV that writes");
    }
    let mut index: [Option<usize>; 10] = [None; 10];
    let mut skipped = Vec::new();
    for (i, name) in headers.iter().enumerate() {
        let Some(k) = COLUMNS.iter().position(|c| *c == name) else {
            let like = COLUMNS.iter().find(|c| loose(c) == loose(name));
            match (opts.extra_columns, like) {
                (ExtraColumns::Ignore, None) => {
                    skipped.push(name.to_string());
                    continue;
                }
                (ExtraColumns::Ignore, Some(c)) => bail!("line 1: column '{name}' looks like '{c}': name it exactly '{c}' (or rename it)"),
                (ExtraColumns::Refuse, _) => bail!("line 1: unknown column '{name}' (known: {})", COLUMNS.join(", ")),
            }
        };
        if index[k].replace(i).is_some() {
            bail!("line 1: column '{name}' appears twice");
        }
    }
    if !skipped.is_empty() {
        notes.push(format!("columns ignored: {}", skipped.join(", ")));
    }
    for required in 0..4 {
        if index[required].is_none() {
            bail!("line 1: required column '{}' is missing", COLUMNS[required]);
        }
    }
    for (a, b) in [(4, 5), (6, 7)] {
        if index[a].is_some() != index[b].is_some() {
            bail!(
                "line 1: columns '{}' and '{}' go together",
                COLUMNS[a],
                COLUMNS[b]
            );
        }
    }
    let mut out = Vec::new();
    for record in csv_dialect::records(&mut reader, headers.len()) {
        let (line, record) = record?;
        let field = |k: usize| index[k].map(|i| &record[i]);
        let number = |k: usize| -> Result<Option<f64>, IoError> {
            match field(k) {
                None | Some("") if k >= 4 => Ok(None),
                None | Some("") => bail!("line {line}: '{}' is empty", COLUMNS[k]),
                Some(s) => csv_dialect::number(s, COLUMNS[k], line, QUANTITIES[k]).map(Some),
            }
        };
        let req = |k: usize| number(k).map(|v| v.expect("required columns are checked above"));
        let pair = |a: usize, b: usize| -> Result<Option<[f64; 2]>, IoError> {
            match (number(a)?, number(b)?) {
                (Some(x), Some(y)) => Ok(Some([x, y])),
                (None, None) => Ok(None),
                _ => bail!(
                    "line {line}: '{}' and '{}' must both be given or both be empty",
                    COLUMNS[a],
                    COLUMNS[b]
                ),
            }
        };
        let dir = match pair(6, 7)? {
            None => None,
            Some(d) => {
                let sign = |v: f64, k: usize| -> Result<i8, IoError> {
                    match v {
                        1.0 => Ok(1),
                        -1.0 => Ok(-1),
                        _ => bail!("line {line}: '{}' must be +1 or -1, not {v}", COLUMNS[k]),
                    }
                };
                Some([sign(d[0], 6)?, sign(d[1], 7)?])
            }
        };
        let run = match number(8)? {
            None => None,
            Some(r) if r >= 0.0 && r.fract() == 0.0 && r <= u32::MAX as f64 => Some(r as u32),
            Some(r) => bail!("line {line}: 'run' must be a non-negative integer, not {r}"),
        };
        out.push(Measurement {
            theta_deg: [req(0)?, req(1)?],
            measured_mm: [req(2)?, req(3)?],
            target_mm: pair(4, 5)?,
            dir,
            run,
            t_s: number(9)?,
            line,
        });
    }
    if out.is_empty() {
        bail!("no data rows after the header");
    }
    Ok(ReadMeasurements {
        rows: out,
        notes,
        machine,
    })
}

/// Formats measurements of `machine` as CSV: its identity line first
/// (`# machine=NAME digest=HEX8`), then [`format_measurements`].
pub fn format_measurements_of(rows: &[Measurement], machine: &MachineIdentity) -> String {
    format!(
        "{}\n{}",
        machine_identity::csv_line(machine),
        format_measurements(rows)
    )
}

/// Formats measurements as CSV, with the optional columns that every row has.
pub fn format_measurements(rows: &[Measurement]) -> String {
    let all = |f: &dyn Fn(&Measurement) -> bool| !rows.is_empty() && rows.iter().all(f);
    let (has_target, has_dir) = (all(&|m| m.target_mm.is_some()), all(&|m| m.dir.is_some()));
    let (has_run, has_t) = (all(&|m| m.run.is_some()), all(&|m| m.t_s.is_some()));
    let mut s = String::from("theta1_deg,theta2_deg,x_mm,y_mm");
    if has_target {
        s.push_str(",x_target_mm,y_target_mm");
    }
    if has_dir {
        s.push_str(",dir1,dir2");
    }
    if has_run {
        s.push_str(",run");
    }
    if has_t {
        s.push_str(",t_s");
    }
    s.push('\n');
    for m in rows {
        // 9 decimals of a degree (~3 nrad) and 6 of a mm (1 nm): below every noise floor here.
        s.push_str(&format!(
            "{:.9},{:.9},{:.6},{:.6}",
            m.theta_deg[0], m.theta_deg[1], m.measured_mm[0], m.measured_mm[1]
        ));
        if let (true, Some(t)) = (has_target, m.target_mm) {
            s.push_str(&format!(",{:.6},{:.6}", t[0], t[1]));
        }
        if let (true, Some(d)) = (has_dir, m.dir) {
            s.push_str(&format!(",{},{}", d[0], d[1]));
        }
        if let (true, Some(r)) = (has_run, m.run) {
            s.push_str(&format!(",{r}"));
        }
        if let (true, Some(t)) = (has_t, m.t_s) {
            s.push_str(&format!(",{t:.6}"));
        }
        s.push('\n');
    }
    s
}

/// Writes measurements atomically.
pub fn write_measurements(path: &Path, rows: &[Measurement]) -> Result<(), IoError> {
    write_atomic(path, format_measurements(rows).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_in_any_order_and_optional_ones() {
        let m = parse_measurements(
            "y_mm,x_mm,theta2_deg,theta1_deg,dir1,dir2\n0,212.132,-45,45,1,-1\n",
        )
        .unwrap();
        assert_eq!(m[0].theta_deg, [45.0, -45.0]);
        assert_eq!(m[0].measured_mm, [212.132, 0.0]);
        assert_eq!(m[0].dir, Some([1, -1]));
        assert_eq!(m[0].line, 2);
    }

    #[test]
    fn other_delimiters_and_extra_columns() {
        let text =
            "theta1_deg;theta2_deg;x_mm;y_mm;point;temperature_c\n45;-45;212.132;0;P1;20.5\n";
        let e = parse_measurements(text).unwrap_err().to_string();
        assert!(e.contains("unknown column 'point'"), "{e}");
        let r = parse_measurements_with(
            text,
            &ReadOptions {
                extra_columns: ExtraColumns::Ignore,
            },
        )
        .unwrap();
        assert_eq!(
            (r.rows[0].theta_deg, r.rows[0].measured_mm),
            ([45.0, -45.0], [212.132, 0.0])
        );
        assert_eq!(
            r.notes,
            vec![
                "semicolon-separated file".to_string(),
                "columns ignored: point, temperature_c".into()
            ]
        );
        let tab = parse_measurements("theta1_deg\ttheta2_deg\tx_mm\ty_mm\n45\t-45\t212.132\t0\n")
            .unwrap();
        assert_eq!(tab[0].measured_mm, [212.132, 0.0]);
        // A misspelt known column is refused even when extra columns are allowed.
        let e = parse_measurements_with(
            "theta1_deg,theta2_deg,x_mm,y_mm,X_Target\n1,2,3,4,5\n",
            &ReadOptions {
                extra_columns: ExtraColumns::Ignore,
            },
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("'X_Target' looks like 'x_target_mm'"), "{e}");
    }

    #[test]
    fn round_trip_through_text() {
        let rows = vec![Measurement {
            theta_deg: [368.689, 319.378],
            measured_mm: [261.82, -74.87],
            target_mm: Some([262.132, -75.0]),
            dir: Some([-1, 1]),
            run: Some(3),
            t_s: Some(1.5),
            line: 0,
        }];
        let back = parse_measurements(&format_measurements(&rows)).unwrap();
        assert_eq!(back[0].theta_deg, rows[0].theta_deg);
        assert_eq!(back[0].target_mm, rows[0].target_mm);
        assert_eq!(back[0].dir, rows[0].dir);
        assert_eq!(back[0].run, Some(3));
    }

    #[test]
    fn errors_name_the_line_and_column() {
        let cases = [
            (
                "theta1_deg,theta2_deg,x_mm\n1,2,3\n",
                "required column 'y_mm'",
            ),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm\n1,2,3,4\n1,2,NaN,4\n",
                "line 3: 'x_mm' = 'NaN' is not finite",
            ),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm\n1,2,3\n",
                "line 2: 3 fields",
            ),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm\n1,2,abc,4\n",
                "line 2: 'x_mm' = 'abc' is not a number",
            ),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm,dir1,dir2\n1,2,3,4,0,1\n",
                "'dir1' must be +1 or -1",
            ),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm,colour\n1,2,3,4,red\n",
                "unknown column 'colour'",
            ),
            ("theta1_deg,theta2_deg,x_mm,y_mm\n", "no data rows"),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm,x_target_mm\n1,2,3,4,5\n",
                "go together",
            ),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm\n1e300,2,3,4\n",
                "line 2: 'theta1_deg' = 1e300 is absurd",
            ),
            (
                "theta1_deg,theta2_deg,x_mm,y_mm\n1,2,1e300,4\n",
                "line 2: 'x_mm' = 1e300 is absurd",
            ),
        ];
        for (text, want) in cases {
            let err = parse_measurements(text).unwrap_err().to_string();
            assert!(
                err.contains(want),
                "for {text:?}: got '{err}', want '{want}'"
            );
        }
    }
}
