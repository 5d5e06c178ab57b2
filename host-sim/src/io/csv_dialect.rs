//! What every CSV the tools read has in common: the delimiter (`,`, `;` or tab, detected from
//! the header line), `#` comments, trimmed fields, and numbers that must be finite and within
//! the range a quantity can have.
//!
//! Why detect the delimiter: instrument software (laser trackers, interferometers) and
//! spreadsheets in many locales write `;` or tab separated files; a user should not have to
//! convert them. The header decides: the candidate that occurs most in it (a header never
//! contains a delimiter inside a field). A `;` file with decimal commas ("212,132") is refused
//! with that hint rather than misread.
//!
//! Why ranges: a finite but absurd value (θ = 1e300°, x = 1e300 mm) is as broken as a NaN and
//! moved a fit's link to 572 mm; [`MAX_ABS_ANGLE_DEG`] and [`MAX_ABS_LENGTH_MM`] are far beyond
//! any real machine (2,777 motor turns; 1 km) and far inside what the arithmetic survives.

use super::IoError;

/// The largest |angle| a file may hold (degrees): 2,777 turns.
pub const MAX_ABS_ANGLE_DEG: f64 = 1e6;
/// The largest |coordinate| a file may hold (mm): 1 km.
pub const MAX_ABS_LENGTH_MM: f64 = 1e6;
/// The largest |time| a file may hold (s): 30,000 years.
pub const MAX_ABS_TIME_S: f64 = 1e12;

/// The delimiter of a CSV text, from its header line (the first line that is not a comment).
pub fn detect_delimiter(text: &str) -> u8 {
    let header = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .unwrap_or("");
    let count = |c: char| header.matches(c).count();
    let mut best = (b',', count(','));
    for (d, c) in [(b';', ';'), (b'\t', '\t')] {
        if count(c) > best.1 {
            best = (d, count(c));
        }
    }
    best.0
}

/// A CSV reader over `text` with the detected delimiter, `#` comments and trimmed fields.
pub fn reader(text: &str) -> csv::Reader<&[u8]> {
    csv::ReaderBuilder::new()
        .delimiter(detect_delimiter(text))
        .trim(csv::Trim::All)
        .flexible(true)
        .comment(Some(b'#'))
        .from_reader(text.as_bytes())
}

/// The data records of `reader` with their lines (1-based, header = 1), each checked to have
/// the header's `fields` fields.
pub fn records<'r, R: std::io::Read + 'r>(
    reader: &'r mut csv::Reader<R>,
    fields: usize,
) -> impl Iterator<Item = Result<(usize, csv::StringRecord), IoError>> + 'r {
    reader.records().map(move |record| {
        let record = record.map_err(|e| IoError::Parse(format!("malformed CSV: {e}")))?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        if record.len() != fields {
            return Err(IoError::Parse(format!(
                "line {line}: {} fields, the header has {fields}",
                record.len()
            )));
        }
        Ok((line, record))
    })
}

/// The columns `a` and `b` of a header, which come together: both (their indices) or neither.
pub fn column_pair(
    headers: &csv::StringRecord,
    a: &str,
    b: &str,
) -> Result<Option<(usize, usize)>, IoError> {
    let at = |name: &str| headers.iter().position(|h| h == name);
    match (at(a), at(b)) {
        (Some(i), Some(j)) => Ok(Some((i, j))),
        (None, None) => Ok(None),
        _ => Err(IoError::Parse(format!(
            "line 1: columns '{a}' and '{b}' come together"
        ))),
    }
}

/// A motor's direction field of column `name`: `1`, `+1` or `-1`.
pub fn direction(s: &str, name: &str, line: usize) -> Result<i8, IoError> {
    match s {
        "1" | "+1" => Ok(1),
        "-1" => Ok(-1),
        v => Err(IoError::Parse(format!(
            "line {line}: '{name}' = '{v}' is not +1 or -1"
        ))),
    }
}

/// A `run` field: a repeat index (0, 1, ...).
pub fn run_index(s: &str, line: usize) -> Result<u32, IoError> {
    s.parse()
        .map_err(|_| IoError::Parse(format!("line {line}: 'run' = '{s}' is not a run index")))
}

/// The name of a delimiter for messages.
pub fn delimiter_name(d: u8) -> &'static str {
    match d {
        b';' => "semicolon",
        b'\t' => "tab",
        _ => "comma",
    }
}

/// The kind of quantity a column holds (its range, see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quantity {
    AngleDeg,
    LengthMm,
    TimeS,
    /// Any finite number.
    Plain,
}

impl Quantity {
    fn limit(self) -> f64 {
        match self {
            Quantity::AngleDeg => MAX_ABS_ANGLE_DEG,
            Quantity::LengthMm => MAX_ABS_LENGTH_MM,
            Quantity::TimeS => MAX_ABS_TIME_S,
            Quantity::Plain => f64::MAX,
        }
    }
}

/// Parses field `s` of column `name` on `line` as a finite number within the quantity's range;
/// the messages name the line and column.
pub fn number(s: &str, name: &str, line: usize, quantity: Quantity) -> Result<f64, IoError> {
    let v: f64 = s.parse().map_err(|_| {
        let hint = if s.contains(',') && s.replace(',', ".").parse::<f64>().is_ok() {
            " (a decimal comma? write a point)"
        } else {
            ""
        };
        IoError::Parse(format!(
            "line {line}: '{name}' = '{s}' is not a number{hint}"
        ))
    })?;
    if !v.is_finite() {
        return Err(IoError::Parse(format!(
            "line {line}: '{name}' = '{s}' is not finite"
        )));
    }
    let limit = quantity.limit();
    if v.abs() > limit {
        return Err(IoError::Parse(format!(
            "line {line}: '{name}' = {v:e} is absurd (|value| above {limit:e})"
        )));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delimiters_and_numbers() {
        assert_eq!(detect_delimiter("# c\nx_mm;y_mm\n1;2\n"), b';');
        assert_eq!(detect_delimiter("x_mm\ty_mm\n"), b'\t');
        assert_eq!(detect_delimiter("x_mm,y_mm\n"), b',');
        assert_eq!(
            number("1e300", "theta1_deg", 3, Quantity::AngleDeg)
                .unwrap_err()
                .to_string(),
            "line 3: 'theta1_deg' = 1e300 is absurd (|value| above 1e6)"
        );
        assert!(number("212,1", "x_mm", 2, Quantity::LengthMm)
            .unwrap_err()
            .to_string()
            .contains("decimal comma"));
        assert!(number("inf", "x_mm", 2, Quantity::LengthMm)
            .unwrap_err()
            .to_string()
            .contains("not finite"));
        assert_eq!(
            number("-368.5", "t", 2, Quantity::AngleDeg).unwrap(),
            -368.5
        );
    }
}
