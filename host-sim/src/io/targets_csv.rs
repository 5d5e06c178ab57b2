//! A list of targets: CSV with the columns `x_mm,y_mm` (any order, `#` comments, `,` `;` or tab
//! separated), what `host-sim command` reads. Every number must be finite and |value| ≤ 1e6 mm;
//! errors name the line (header = 1).
//!
//! A plan's list (`host-sim plan`, what `measure --targets` and a real session consume) adds
//! optional columns, each pair both or neither; other columns are refused:
//!
//! | column | meaning |
//! |---|---|
//! | `x_mm`, `y_mm` | the target (machine frame) |
//! | `from_x_mm`, `from_y_mm` | where the final move towards the target starts (the approach) |
//! | `dir1`, `dir2` | `+1`/`-1`: the direction each motor must be moving when it arrives |
//! | `run` | the repeat index (ISO 230-2 runs; 0 elsewhere) |
//!
//! Coordinates are written with every digit (`{}`, shortest round trip): a list read back is
//! the list planned, bit for bit. `command` reads plan lists too (it uses `x_mm,y_mm`).

use super::csv_dialect::{column_pair, direction, number, records, run_index, Quantity};
use super::{read_text, IoError};
use std::path::Path;

/// One target and the file line it came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Target {
    pub line: usize,
    pub target_mm: [f64; 2],
}

/// One row of a plan's list (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ListedTarget {
    /// Line in the file (1-based; 0 for rows not read from a file).
    pub line: usize,
    pub target_mm: [f64; 2],
    pub from_mm: Option<[f64; 2]>,
    pub dir: Option<[i8; 2]>,
    pub run: Option<u32>,
}

/// The columns a targets file may have.
const COLUMNS: [&str; 7] = [
    "x_mm",
    "y_mm",
    "from_x_mm",
    "from_y_mm",
    "dir1",
    "dir2",
    "run",
];

/// Parses a targets CSV text.
pub fn parse_targets(text: &str) -> Result<Vec<Target>, IoError> {
    Ok(parse_target_list(text)?
        .into_iter()
        .map(|t| Target {
            line: t.line,
            target_mm: t.target_mm,
        })
        .collect())
}

/// Parses a targets CSV text with the plan's optional columns.
pub fn parse_target_list(text: &str) -> Result<Vec<ListedTarget>, IoError> {
    let parse = |m: String| IoError::Parse(m);
    let mut reader = super::csv_dialect::reader(text);
    let headers = reader
        .headers()
        .map_err(|e| parse(format!("line 1: cannot read the header: {e}")))?
        .clone();
    let col = |name: &str| {
        headers
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| parse(format!("line 1: required column '{name}' is missing")))
    };
    let (ix, iy) = (col("x_mm")?, col("y_mm")?);
    if let Some(h) = headers.iter().find(|h| !COLUMNS.contains(h)) {
        return Err(parse(format!(
            "line 1: unknown column '{h}' (a targets file has x_mm,y_mm and optionally from_x_mm,from_y_mm, dir1,dir2, run)"
        )));
    }
    let optional = |name: &str| headers.iter().position(|h| h == name);
    let (from, dir, run) = (
        column_pair(&headers, "from_x_mm", "from_y_mm")?,
        column_pair(&headers, "dir1", "dir2")?,
        optional("run"),
    );
    let mut out = Vec::new();
    for record in records(&mut reader, headers.len()) {
        let (line, record) = record?;
        let num = |i: usize, name: &str| number(&record[i], name, line, Quantity::LengthMm);
        let from_mm = match from {
            Some((i, j)) => Some([num(i, "from_x_mm")?, num(j, "from_y_mm")?]),
            None => None,
        };
        let dir = match dir {
            Some((i, j)) => Some([
                direction(&record[i], "dir1", line)?,
                direction(&record[j], "dir2", line)?,
            ]),
            None => None,
        };
        let run = run.map(|i| run_index(&record[i], line)).transpose()?;
        out.push(ListedTarget {
            line,
            target_mm: [num(ix, "x_mm")?, num(iy, "y_mm")?],
            from_mm,
            dir,
            run,
        });
    }
    if out.is_empty() {
        return Err(parse("no targets after the header".into()));
    }
    Ok(out)
}

/// Reads a targets file.
pub fn read_targets(path: &Path) -> Result<Vec<Target>, IoError> {
    parse_targets(&read_text(path)?).map_err(|e| IoError::content(path, e))
}

/// Reads a targets file with the plan's optional columns.
pub fn read_target_list(path: &Path) -> Result<Vec<ListedTarget>, IoError> {
    parse_target_list(&read_text(path)?).map_err(|e| IoError::content(path, e))
}

/// A plan's list as CSV: `x_mm,y_mm`, then each optional pair every row has.
pub fn format_target_list(rows: &[ListedTarget]) -> String {
    let all = |f: &dyn Fn(&ListedTarget) -> bool| !rows.is_empty() && rows.iter().all(f);
    let (has_from, has_dir, has_run) = (
        all(&|t| t.from_mm.is_some()),
        all(&|t| t.dir.is_some()),
        all(&|t| t.run.is_some()),
    );
    let mut s = String::from("x_mm,y_mm");
    for (has, cols) in [
        (has_from, ",from_x_mm,from_y_mm"),
        (has_dir, ",dir1,dir2"),
        (has_run, ",run"),
    ] {
        if has {
            s.push_str(cols);
        }
    }
    s.push('\n');
    for t in rows {
        s.push_str(&format!("{},{}", t.target_mm[0], t.target_mm[1]));
        if let (true, Some(f)) = (has_from, t.from_mm) {
            s.push_str(&format!(",{},{}", f[0], f[1]));
        }
        if let (true, Some(d)) = (has_dir, t.dir) {
            s.push_str(&format!(",{},{}", d[0], d[1]));
        }
        if let (true, Some(r)) = (has_run, t.run) {
            s.push_str(&format!(",{r}"));
        }
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_comments_and_errors() {
        let t = parse_targets("y_mm,x_mm\n0,212.132\n-5,200\n# comment\n").unwrap();
        assert_eq!(
            t,
            vec![
                Target {
                    line: 2,
                    target_mm: [212.132, 0.0]
                },
                Target {
                    line: 3,
                    target_mm: [200.0, -5.0]
                }
            ]
        );
        for (text, want) in [
            (
                "x_mm,y_mm\n181,nan\n",
                "line 2: 'y_mm' = 'nan' is not finite",
            ),
            ("x_mm\n1\n", "required column 'y_mm'"),
            ("x_mm,y_mm,z_mm\n1,2,3\n", "unknown column 'z_mm'"),
            ("x_mm,y_mm\n", "no targets"),
            ("x_mm,y_mm,dir1\n1,2,1\n", "'dir1' and 'dir2' come together"),
            (
                "x_mm,y_mm,dir1,dir2\n1,2,1,0\n",
                "line 2: 'dir2' = '0' is not +1 or -1",
            ),
            (
                "x_mm,y_mm,run\n1,2,-1\n",
                "line 2: 'run' = '-1' is not a run index",
            ),
            (
                "x_mm,y_mm,from_x_mm,from_y_mm\n1,2,inf,0\n",
                "line 2: 'from_x_mm' = 'inf' is not finite",
            ),
        ] {
            let e = parse_targets(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn a_plan_list_round_trips_bit_for_bit() {
        let rows = vec![
            ListedTarget {
                line: 0,
                target_mm: [212.13199999999998, -0.1 + 0.2],
                from_mm: Some([207.1, 1e-17]),
                dir: Some([1, -1]),
                run: Some(3),
            },
            ListedTarget {
                line: 0,
                target_mm: [162.132, 75.0],
                from_mm: Some([157.132, 75.0]),
                dir: Some([-1, 1]),
                run: Some(0),
            },
        ];
        let text = format_target_list(&rows);
        assert!(
            text.starts_with("x_mm,y_mm,from_x_mm,from_y_mm,dir1,dir2,run\n"),
            "{text}"
        );
        let back = parse_target_list(&text).unwrap();
        for (a, b) in rows.iter().zip(&back) {
            assert_eq!(ListedTarget { line: 0, ..*b }, *a);
        }
        // `command` reads the same file.
        assert_eq!(parse_targets(&text).unwrap()[1].target_mm, [162.132, 75.0]);
    }
}
