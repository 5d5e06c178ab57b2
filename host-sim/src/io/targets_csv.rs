//! A list of targets: CSV with the columns `x_mm,y_mm` (any order, `#` comments, `,` `;` or tab
//! separated), what `host-sim command` reads. Every number must be finite and |value| ≤ 1e6 mm;
//! errors name the line (header = 1).

use super::{read_text, IoError};
use std::path::Path;

/// One target and the file line it came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Target {
    pub line: usize,
    pub target_mm: [f64; 2],
}

/// Parses a targets CSV text.
pub fn parse_targets(text: &str) -> Result<Vec<Target>, IoError> {
    let parse = |m: String| IoError::Parse(m);
    let mut reader = super::csv_dialect::reader(text);
    let headers = reader.headers().map_err(|e| parse(format!("line 1: cannot read the header: {e}")))?.clone();
    let col = |name: &str| {
        headers.iter().position(|h| h == name).ok_or_else(|| parse(format!("line 1: required column '{name}' is missing")))
    };
    let (ix, iy) = (col("x_mm")?, col("y_mm")?);
    if let Some(h) = headers.iter().find(|h| *h != "x_mm" && *h != "y_mm") {
        return Err(parse(format!("line 1: unknown column '{h}' (a targets file has x_mm,y_mm)")));
    }
    let mut out = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| parse(format!("malformed CSV: {e}")))?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        if record.len() != headers.len() {
            return Err(parse(format!("line {line}: {} fields, the header has {}", record.len(), headers.len())));
        }
        let num = |i: usize, name: &str| super::csv_dialect::number(&record[i], name, line, super::csv_dialect::Quantity::LengthMm);
        out.push(Target { line, target_mm: [num(ix, "x_mm")?, num(iy, "y_mm")?] });
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_comments_and_errors() {
        let t = parse_targets("y_mm,x_mm\n0,212.132\n-5,200\n# comment\n").unwrap();
        assert_eq!(t, vec![Target { line: 2, target_mm: [212.132, 0.0] }, Target { line: 3, target_mm: [200.0, -5.0] }]);
        for (text, want) in [
            ("x_mm,y_mm\n181,nan\n", "line 2: 'y_mm' = 'nan' is not finite"),
            ("x_mm\n1\n", "required column 'y_mm'"),
            ("x_mm,y_mm,z_mm\n1,2,3\n", "unknown column 'z_mm'"),
            ("x_mm,y_mm\n", "no targets"),
        ] {
            let e = parse_targets(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }
}
