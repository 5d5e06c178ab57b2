//! The instrument of a session on a real machine: a reading typed in at each point, or none now
//! (the laser tracker records the points in its own software and its export is joined with the
//! session's angles afterwards by `host-sim import`). The co-simulation's instrument (the
//! plant's tool point through the instrument's frame, scale and noise) is the co-simulated
//! rig's own.

use super::{PointRequest, Reading, SessionError};
use std::io::{BufRead, Write};

/// Reads the tool point at a settled pose.
pub trait Instrument {
    /// One line for reports.
    fn describe(&self) -> String;
    /// The reading at `point`.
    fn read(&mut self, point: &PointRequest) -> Result<Reading, SessionError>;
    /// Where the tool really was at the last reading, as a noiseless instrument would read it:
    /// known in simulation only.
    fn last_truth_mm(&self) -> Option<[f64; 2]> {
        None
    }
}

/// No reading now: the tracker's export is joined later by `import` (the session writes the
/// angles it held, point by point, as the commanded list `import --commanded` reads).
pub struct Deferred;

impl Instrument for Deferred {
    fn describe(&self) -> String {
        "readings from the tracker's export, joined afterwards by host-sim import".into()
    }

    fn read(&mut self, _point: &PointRequest) -> Result<Reading, SessionError> {
        Ok(Reading::Deferred)
    }
}

/// A reading typed in at each point: `x y` in mm (spaces, a comma or a semicolon between
/// them), an empty line for a point the instrument could not see. A line that is not two
/// finite numbers is asked again, three times at most.
pub struct TypedIn<R: BufRead, W: Write> {
    input: R,
    prompt: W,
}

impl<R: BufRead, W: Write> TypedIn<R, W> {
    /// Reads from `input`, prompting on `prompt`.
    pub fn new(input: R, prompt: W) -> Self {
        TypedIn { input, prompt }
    }
}

/// `x y` (mm) from a typed line; `Ok(None)` for an empty line.
pub fn parse_typed(line: &str) -> Result<Option<[f64; 2]>, String> {
    let fields: Vec<&str> = line
        .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
        .filter(|f| !f.is_empty())
        .collect();
    match fields.as_slice() {
        [] => Ok(None),
        [x, y] => {
            let v = [x, y].map(|f| f.parse::<f64>());
            match v {
                [Ok(x), Ok(y)] if x.is_finite() && y.is_finite() => Ok(Some([x, y])),
                _ => Err(format!("'{}' is not two numbers (x y in mm)", line.trim())),
            }
        }
        _ => Err(format!(
            "'{}' has {} fields: give x y in mm, or an empty line if the point was not seen",
            line.trim(),
            fields.len()
        )),
    }
}

impl<R: BufRead, W: Write> Instrument for TypedIn<R, W> {
    fn describe(&self) -> String {
        "readings typed in".into()
    }

    fn read(&mut self, point: &PointRequest) -> Result<Reading, SessionError> {
        let fail = |reason: String| SessionError::Reading {
            point: point.id.clone(),
            reason,
        };
        for _ in 0..3 {
            write!(
                self.prompt,
                "{} at ({:.3}, {:.3}) mm: the instrument's x y in mm (empty: not seen)? ",
                point.id, point.target_mm[0], point.target_mm[1]
            )
            .and_then(|_| self.prompt.flush())
            .map_err(|e| fail(format!("cannot be asked for: {e}")))?;
            let mut line = String::new();
            let n = self
                .input
                .read_line(&mut line)
                .map_err(|e| fail(format!("cannot be read: {e}")))?;
            if n == 0 {
                return Err(fail(
                    "was not given: the input ended (the session stops; nothing is written)".into(),
                ));
            }
            match parse_typed(&line) {
                Ok(Some(p)) => return Ok(Reading::Point(p)),
                Ok(None) => return Ok(Reading::Missing),
                Err(e) => {
                    let _ = writeln!(self.prompt, "{e}");
                }
            }
        }
        Err(fail("was refused three times (x y in mm)".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn typed_readings_are_parsed_and_bad_ones_asked_again() {
        assert_eq!(parse_typed("212.5 -3.25\n"), Ok(Some([212.5, -3.25])));
        assert_eq!(parse_typed("212.5;-3.25"), Ok(Some([212.5, -3.25])));
        assert_eq!(parse_typed("  \n"), Ok(None));
        assert!(parse_typed("212.5").is_err());
        assert!(parse_typed("NaN 1").is_err());
        let p = PointRequest {
            index: 0,
            id: "P001".into(),
            target_mm: [212.0, 0.0],
            encoder_rad: [0.7, -0.7],
        };
        let mut out = Vec::new();
        let mut t = TypedIn::new(&b"abc\n1 2 3\n212.001 0.002\n"[..], &mut out);
        assert_eq!(t.read(&p).unwrap(), Reading::Point([212.001, 0.002]));
        let mut t = TypedIn::new(&b"\n"[..], Vec::new());
        assert_eq!(t.read(&p).unwrap(), Reading::Missing);
        let mut t = TypedIn::new(&b"x\ny\nz\n"[..], Vec::new());
        assert!(t.read(&p).is_err());
        let mut t = TypedIn::new(&b""[..], Vec::new());
        assert!(t.read(&p).unwrap_err().to_string().contains("input ended"));
    }
}
