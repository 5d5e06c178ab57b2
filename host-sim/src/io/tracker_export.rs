//! A laser tracker's or interferometer's point export, read through a column map: one row per
//! measured point with the vendor's own point id and X, Y[, Z] columns. What `host-sim import`
//! joins with the commanded list (`calib::import`).
//!
//! Why a column map rather than a fixed format: every vendor names, orders and delimits its
//! columns differently (`Point;X [mm];Y [mm];Z [mm];RMS`, `Name,X,Y,Z`, tab-separated, in
//! metres, with a few lines of job metadata on top). [`ColumnMap`] says which column is the id,
//! x, y and optionally z; everything else is the vendor's and is tolerated:
//!
//! * **Metadata lines** before the header (job name, instrument, date) are skipped: the header is
//!   the first line (of the first 100) that holds every mapped column name as a field, with `;`,
//!   tab or `,` as the delimiter (tried in that order). Lines starting with `#` are comments.
//! * **Extra columns** (RMS, time, temperature) are ignored and named in a note.
//! * **Units:** [`LengthUnit`]; when not given, the mapped columns' headers decide (`X [m]`,
//!   `X (mm)`, `X_m`), and a header without a unit means mm. A unit given that contradicts a
//!   header's is refused.
//! * **Numbers:** decimal point, or a decimal comma when [`ExportFormat::decimal_comma`] says so
//!   (then the delimiter must be `;` or tab); finite, |value| ≤ 1e6 mm after scaling
//!   ([`super::csv_dialect::number`]: a decimal comma is refused with that hint); errors name
//!   the line (1-based in the file, metadata counted) and the column.

use super::csv_dialect::{self, Quantity, MAX_ABS_LENGTH_MM};
use super::text_source::TextLines;
use super::IoError;
use std::fmt;
use std::path::Path;

/// A format error: the message names the line and column.
macro_rules! bail {
    ($($t:tt)*) => { return Err(IoError::Parse(format!($($t)*))) };
}

/// How many lines may precede the header (metadata).
pub const MAX_HEADER_LINE: usize = 100;
/// The largest export read (bytes): a session of 100,000 points is ~6 MB.
pub const MAX_EXPORT_BYTES: u64 = 64 * 1024 * 1024;
/// The most points an export may hold (a session's lists hold hundreds to thousands).
pub const MAX_POINTS: usize = 200_000;
/// Without a stated unit, mm is taken when the points spread between these fractions of the
/// workspace's extent (its bounding diagonal); metres and µm are 1000x outside either bound.
pub const SCALE_EVIDENCE: [f64; 2] = [0.01, 10.0];

/// Which export column holds what (`id=Point,x=X [mm],y=Y [mm],z=Z [mm]`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ColumnMap {
    pub id: String,
    pub x: String,
    pub y: String,
    pub z: Option<String>,
}

impl ColumnMap {
    /// Parses `key=Column,...` with the keys `id`, `x`, `y` (required) and `z` (optional).
    /// Column names are taken as written (spaces inside kept, ends trimmed).
    pub fn parse(text: &str) -> Result<ColumnMap, IoError> {
        let (mut id, mut x, mut y, mut z) = (None, None, None, None);
        for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let Some((key, column)) = part.split_once('=') else {
                bail!("column map: '{part}' is not key=Column (keys: id, x, y, z)");
            };
            let (key, column) = (key.trim(), column.trim());
            if column.is_empty() {
                bail!("column map: '{key}' names no column");
            }
            let slot = match key {
                "id" => &mut id,
                "x" => &mut x,
                "y" => &mut y,
                "z" => &mut z,
                _ => bail!("column map: unknown key '{key}' (keys: id, x, y, z)"),
            };
            if slot.replace(column.to_string()).is_some() {
                bail!("column map: '{key}' is given twice");
            }
        }
        let need = |v: Option<String>, key: &str| {
            v.ok_or_else(|| {
                IoError::Parse(format!(
                    "column map: '{key}=COLUMN' is missing (id, x and y are required)"
                ))
            })
        };
        let map = ColumnMap {
            id: need(id, "id")?,
            x: need(x, "x")?,
            y: need(y, "y")?,
            z,
        };
        let names = map.names();
        for (i, a) in names.iter().enumerate() {
            if names[..i].contains(a) {
                bail!("column map: column '{a}' is mapped twice");
            }
        }
        Ok(map)
    }

    /// The mapped column names: id, x, y[, z].
    pub fn names(&self) -> Vec<&str> {
        let mut v = vec![self.id.as_str(), self.x.as_str(), self.y.as_str()];
        v.extend(self.z.as_deref());
        v
    }
}

/// The unit of the export's coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LengthUnit {
    Mm,
    M,
    /// Micrometres (`µm`, `um`).
    Um,
}

impl LengthUnit {
    /// Millimetres per unit.
    pub fn to_mm(self) -> f64 {
        match self {
            LengthUnit::Mm => 1.0,
            LengthUnit::M => 1000.0,
            LengthUnit::Um => 1e-3,
        }
    }

    /// The unit a column header states (`X [m]`, `X (mm)`, `x_m`, `X/mm`, `X [µm]`, `X [um]`),
    /// if any.
    pub fn from_header(name: &str) -> Option<LengthUnit> {
        let n = name.trim().to_lowercase();
        let bracketed = |u: &str| {
            ["[", "(", "/", "_", " ", "in "].iter().any(|open| {
                n.ends_with(&format!("{open}{u}"))
                    || n.ends_with(&format!("{open}{u}]"))
                    || n.ends_with(&format!("{open}{u})"))
            })
        };
        if bracketed("mm") {
            Some(LengthUnit::Mm)
        } else if bracketed("um") || bracketed("µm") || bracketed("\u{3bc}m") {
            Some(LengthUnit::Um)
        } else if bracketed("m") {
            Some(LengthUnit::M)
        } else {
            None
        }
    }
}

impl fmt::Display for LengthUnit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            LengthUnit::Mm => "mm",
            LengthUnit::M => "m",
            LengthUnit::Um => "um",
        })
    }
}

/// One measured point of the export.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportPoint {
    /// Line in the file (1-based, metadata lines counted).
    pub line: usize,
    /// The point id as written (trimmed).
    pub id: String,
    /// X, Y in mm (scaled from the export's unit).
    pub xy_mm: [f64; 2],
    /// Z in mm, when the map names a z column.
    pub z_mm: Option<f64>,
}

/// An export read: its points and what the reader noticed.
#[derive(Clone, Debug, PartialEq)]
pub struct Export {
    pub points: Vec<ExportPoint>,
    /// The header's line (1-based); the lines before it were metadata.
    pub header_line: usize,
    pub delimiter: u8,
    pub unit: LengthUnit,
    /// The export's columns the map does not name (ignored).
    pub ignored_columns: Vec<String>,
    /// What a user should know (metadata skipped, delimiter, columns ignored, unit inferred).
    pub notes: Vec<String>,
}

/// A header field as written, without surrounding quotes (nor a UTF-8 byte-order mark, which
/// Windows tools put before the first).
fn field_name(f: &str) -> &str {
    f.trim_start_matches('\u{feff}')
        .trim()
        .trim_matches('"')
        .trim()
}

/// A header line's fields with delimiter `d`.
fn split_header(line: &str, d: u8) -> Vec<String> {
    line.split(d as char)
        .map(|f| field_name(f).to_string())
        .collect()
}

/// The delimiter and fields of `line` if it holds every name of `wanted` as a field.
fn header_fields(line: &str, wanted: &[&str]) -> Option<(u8, Vec<String>)> {
    if line.trim().is_empty() || line.trim_start().starts_with('#') {
        return None;
    }
    [b';', b'\t', b','].into_iter().find_map(|d| {
        let fields = split_header(line, d);
        wanted
            .iter()
            .all(|w| fields.iter().any(|f| f == w))
            .then_some((d, fields))
    })
}

/// A data line's fields: split at `d` outside double quotes, each trimmed and unquoted. Why
/// not the `csv` crate here: the export is streamed a line at a time (`text_source`), and a
/// row is one line.
fn split_row(line: &str, d: u8) -> Vec<String> {
    let (mut fields, mut cur, mut quoted) = (Vec::new(), String::new(), false);
    for c in line.chars() {
        match c {
            '"' => quoted = !quoted,
            c if !quoted && c == d as char => fields.push(std::mem::take(&mut cur)),
            c => cur.push(c),
        }
    }
    fields.push(cur);
    fields.iter().map(|f| f.trim().to_string()).collect()
}

/// The header: the first line (not a comment, within [`MAX_HEADER_LINE`]) holding every mapped
/// name as a field. Returns its index (0-based), delimiter and fields.
fn find_header(lines: &[&str], map: &ColumnMap) -> Result<(usize, u8, Vec<String>), IoError> {
    let wanted = map.names();
    let mut widest: Option<(usize, Vec<String>)> = None;
    for (i, line) in lines.iter().enumerate().take(MAX_HEADER_LINE) {
        if line.trim().is_empty() || line.trim_start().starts_with('#') {
            continue;
        }
        if let Some((d, fields)) = header_fields(line, &wanted) {
            return Ok((i, d, fields));
        }
        for d in [b';', b'\t', b','] {
            let fields = split_header(line, d);
            if fields.len() > widest.as_ref().map_or(1, |w| w.1.len()) {
                widest = Some((i, fields));
            }
        }
    }
    let missing = |fields: &[String]| {
        wanted
            .iter()
            .filter(|w| !fields.iter().any(|f| f == *w))
            .map(|w| format!("'{w}'"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    match widest {
        Some((i, fields)) => {
            let like: Vec<String> = wanted
                .iter()
                .filter_map(|w| {
                    fields
                        .iter()
                        .find(|f| f.eq_ignore_ascii_case(w) && f != w)
                        .map(|f| format!("'{f}' for '{w}'"))
                })
                .collect();
            let hint = if like.is_empty() {
                String::new()
            } else {
                format!(" (names are exact: {}?)", like.join(", "))
            };
            bail!(
                "the column map names {} but no line has it; the header looks like line {}: {}{hint}",
                missing(&fields),
                i + 1,
                fields.iter().map(|f| format!("'{f}'")).collect::<Vec<_>>().join(", ")
            )
        }
        None => bail!(
            "no header line with the columns {} (and no line with two or more fields)",
            missing(&[])
        ),
    }
}

/// How the export writes its numbers.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExportFormat {
    /// The coordinates' unit, or `None` to take it from the headers (mm when they state none).
    pub unit: Option<LengthUnit>,
    /// Numbers are written with a decimal comma (`212,132`; a `;` or tab delimiter).
    pub decimal_comma: bool,
    /// The machine's workspace extent (mm, its bounding diagonal): with no unit stated, the
    /// points' spread against it decides mm or refuses ([`SCALE_EVIDENCE`]). `None`: mm.
    pub workspace_extent_mm: Option<f64>,
}

/// Parses an export's text through `map`, numbers with a decimal point. `unit`: the
/// coordinates' unit, or `None` to take it from the headers (mm when they state none).
pub fn parse_export(
    text: &str,
    map: &ColumnMap,
    unit: Option<LengthUnit>,
) -> Result<Export, IoError> {
    parse_export_with(
        text,
        map,
        ExportFormat {
            unit,
            decimal_comma: false,
            workspace_extent_mm: None,
        },
    )
}

/// Parses an export's text through `map` in `format`.
pub fn parse_export_with(
    text: &str,
    map: &ColumnMap,
    format: ExportFormat,
) -> Result<Export, IoError> {
    parse_lines(
        text.lines()
            .enumerate()
            .map(|(i, l)| Ok((i + 1, l.to_string()))),
        map,
        format,
    )
}

/// Reads an export file through `map` in `format`, streamed a line at a time
/// (`super::text_source`: UTF-8, UTF-16 or Latin-1, at most [`MAX_EXPORT_BYTES`] and
/// [`MAX_POINTS`] points): memory is the points read, never the file.
pub fn read_export(path: &Path, map: &ColumnMap, format: ExportFormat) -> Result<Export, IoError> {
    let mut lines = TextLines::open(path, MAX_EXPORT_BYTES)?;
    let mut export = parse_lines(&mut lines, map, format).map_err(|e| IoError::content(path, e))?;
    if let Some(n) = lines.note() {
        export.notes.insert(0, n);
    }
    Ok(export)
}

/// The export's lines (numbered from 1) through `map` in `format`.
fn parse_lines(
    mut lines: impl Iterator<Item = Result<(usize, String), IoError>>,
    map: &ColumnMap,
    format: ExportFormat,
) -> Result<Export, IoError> {
    let wanted = map.names();
    let mut head: Vec<String> = Vec::new();
    while head.len() < MAX_HEADER_LINE {
        let Some(line) = lines.next() else { break };
        let (_, line) = line?;
        let found = header_fields(&line, &wanted).is_some();
        head.push(line);
        if found {
            break;
        }
    }
    let refs: Vec<&str> = head.iter().map(String::as_str).collect();
    let (h, delimiter, fields) = find_header(&refs, map)?;
    if format.decimal_comma && delimiter == b',' {
        bail!(
            "line {}: the export is comma-separated, so its numbers cannot have a decimal comma",
            h + 1
        );
    }
    let header_line = h + 1;
    let col = |name: &str| {
        fields
            .iter()
            .position(|f| f == name)
            .expect("find_header checked every mapped name")
    };
    for name in map.names() {
        if fields.iter().filter(|f| *f == name).count() > 1 {
            bail!("line {header_line}: column '{name}' appears twice");
        }
    }
    let (ii, ix, iy, iz) = (
        col(&map.id),
        col(&map.x),
        col(&map.y),
        map.z.as_deref().map(col),
    );
    let stated: Vec<(&str, LengthUnit)> = map.names()[1..]
        .iter()
        .filter_map(|n| LengthUnit::from_header(n).map(|u| (*n, u)))
        .collect();
    let mut notes = Vec::new();
    let (unit, assumed) = match (format.unit, stated.first()) {
        (Some(u), _) => {
            if let Some((n, s)) = stated.iter().find(|(_, s)| *s != u) {
                bail!("line {header_line}: column '{n}' says {s} but the unit given is {u}");
            }
            (u, false)
        }
        (None, Some(&(_, u))) => {
            if let Some((n, s)) = stated.iter().find(|(_, s)| *s != u) {
                bail!("line {header_line}: the columns disagree on the unit ('{n}' says {s}, '{}' says {u})", stated[0].0);
            }
            notes.push(format!("unit {u}, from the header"));
            (u, false)
        }
        (None, None) => (LengthUnit::Mm, true),
    };
    if h > 0 {
        notes.push(format!("{h} line(s) before the header skipped (metadata)"));
    }
    if delimiter != b',' {
        notes.push(format!(
            "{}-separated file",
            csv_dialect::delimiter_name(delimiter)
        ));
    }
    let mapped = map.names();
    let ignored_columns: Vec<String> = fields
        .iter()
        .filter(|f| !f.is_empty() && !mapped.contains(&f.as_str()))
        .cloned()
        .collect();
    if !ignored_columns.is_empty() {
        notes.push(format!("columns ignored: {}", ignored_columns.join(", ")));
    }
    // The data: the lines after the header (those read while looking for it first). No line
    // is a comment here: a point id may start with '#'.
    let rest = head.split_off(h + 1);
    let data = rest
        .into_iter()
        .enumerate()
        .map(|(k, l)| Ok((header_line + 1 + k, l)))
        .chain(lines);
    let scale = unit.to_mm();
    let mut points = Vec::new();
    for item in data {
        let (line, text) = item?;
        let record = split_row(&text, delimiter);
        if record.iter().all(String::is_empty) {
            continue;
        }
        if record.len() != fields.len() {
            bail!(
                "line {line}: {} fields, the header (line {header_line}) has {}",
                record.len(),
                fields.len()
            );
        }
        if points.len() == MAX_POINTS {
            bail!("line {line}: more than {MAX_POINTS} points, the most an export may hold (a session's list is far shorter: is it the right file?)");
        }
        let id = record[ii].clone();
        if id.is_empty() {
            bail!("line {line}: the point id ('{}') is empty", map.id);
        }
        let coordinate = |i: usize, name: &str| -> Result<f64, IoError> {
            let s = &record[i];
            if s.is_empty() {
                bail!("line {line}: '{name}' is empty (point {id})");
            }
            let v = match format.decimal_comma {
                true => csv_dialect::number(&s.replace(',', "."), name, line, Quantity::Plain),
                false => csv_dialect::number(s, name, line, Quantity::Plain).map_err(|e| {
                    match e.to_string() {
                        m if m.contains("decimal comma") => IoError::Parse(format!(
                            "{m}, or read the file with decimal commas (--decimal-comma)"
                        )),
                        _ => e,
                    }
                }),
            }? * scale;
            if v.abs() > MAX_ABS_LENGTH_MM {
                bail!("line {line}: '{name}' = {s} {unit} is absurd (|value| above {MAX_ABS_LENGTH_MM:e} mm)");
            }
            Ok(v)
        };
        let xy_mm = [coordinate(ix, &map.x)?, coordinate(iy, &map.y)?];
        let z_mm = match (iz, &map.z) {
            (Some(i), Some(name)) => Some(coordinate(i, name)?),
            _ => None,
        };
        points.push(ExportPoint {
            line,
            id,
            xy_mm,
            z_mm,
        });
    }
    if points.is_empty() {
        bail!("no points after the header (line {header_line})");
    }
    if assumed {
        notes.push(assumed_mm(&points, format.workspace_extent_mm)?);
    }
    Ok(Export {
        points,
        header_line,
        delimiter,
        unit,
        ignored_columns,
        notes,
    })
}

/// The points' spread: the diagonal of their bounding rectangle (mm as read).
fn spread_mm(points: &[ExportPoint]) -> f64 {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        for k in 0..2 {
            lo[k] = lo[k].min(p.xy_mm[k]);
            hi[k] = hi[k].max(p.xy_mm[k]);
        }
    }
    (hi[0] - lo[0]).hypot(hi[1] - lo[1])
}

/// No unit stated: mm, if the points' spread fits the machine's workspace (between
/// [`SCALE_EVIDENCE`]'s bounds of its extent); else refused with the evidence and the unit it
/// looks like. Returns the note.
fn assumed_mm(points: &[ExportPoint], extent_mm: Option<f64>) -> Result<String, IoError> {
    let spread = spread_mm(points);
    let Some(ws) = extent_mm else {
        return Ok("no unit in the header: mm assumed (give the unit if it is not)".into());
    };
    if points.len() < 2 || spread == 0.0 {
        return Ok(
            "no unit in the header and one point position: mm assumed (give the unit if it is not)"
                .into(),
        );
    }
    let [lo, hi] = SCALE_EVIDENCE;
    if spread >= lo * ws && spread <= hi * ws {
        return Ok(format!(
            "no unit in the header: mm, as the points' spread says ({spread:.1} mm across, the workspace {ws:.1} mm)"
        ));
    }
    let looks = [LengthUnit::M, LengthUnit::Um]
        .into_iter()
        .find(|u| {
            let s = spread * u.to_mm();
            s >= lo * ws && s <= hi * ws
        })
        .map_or("another unit".to_string(), |u| {
            format!("{u}: give --units {u}")
        });
    bail!(
        "no unit in the header or given, and as mm the points spread {spread:.4} mm across where the machine's workspace is {ws:.1} mm across: the export looks like {looks} (or --units mm if it is mm)"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(text: &str) -> ColumnMap {
        ColumnMap::parse(text).unwrap()
    }

    #[test]
    fn column_maps() {
        assert_eq!(
            map("id=Point, x=X [mm],y=Y [mm],z=Z [mm]"),
            ColumnMap {
                id: "Point".into(),
                x: "X [mm]".into(),
                y: "Y [mm]".into(),
                z: Some("Z [mm]".into())
            }
        );
        assert_eq!(map("x=X,y=Y,id=Name").z, None);
        for (text, want) in [
            ("id=Point,x=X", "'y=COLUMN' is missing"),
            ("id=Point,x=X,y=Y,w=W", "unknown key 'w'"),
            ("id=Point,x=X,x=X2,y=Y", "'x' is given twice"),
            ("id=Point,x=X,y=X", "column 'X' is mapped twice"),
            ("id=Point,x,y=Y", "'x' is not key=Column"),
            ("id=,x=X,y=Y", "'id' names no column"),
        ] {
            let e = ColumnMap::parse(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text}: {e}");
        }
    }

    #[test]
    fn units_from_headers() {
        assert_eq!(LengthUnit::from_header("X [mm]"), Some(LengthUnit::Mm));
        assert_eq!(LengthUnit::from_header("X [m]"), Some(LengthUnit::M));
        assert_eq!(LengthUnit::from_header("x_m"), Some(LengthUnit::M));
        assert_eq!(LengthUnit::from_header("Y (mm)"), Some(LengthUnit::Mm));
        assert_eq!(LengthUnit::from_header("Y/m"), Some(LengthUnit::M));
        assert_eq!(LengthUnit::from_header("X [um]"), Some(LengthUnit::Um));
        assert_eq!(LengthUnit::from_header("X [µm]"), Some(LengthUnit::Um));
        assert_eq!(LengthUnit::from_header("x_um"), Some(LengthUnit::Um));
        assert_eq!(LengthUnit::from_header("X"), None);
        assert_eq!(LengthUnit::from_header("Norm"), None);
    }

    #[test]
    fn a_semicolon_export_with_metadata_and_extra_columns() {
        let text = "Job;Cal 2026-11-23\nInstrument;AT960 #1234\n\nPoint;X [mm];Y [mm];Z [mm];RMS\nP001;212.132;0.5;10.001;0.004\nP002;200;-5.25;10.002;0.005\n";
        let e = parse_export(text, &map("id=Point,x=X [mm],y=Y [mm],z=Z [mm]"), None).unwrap();
        assert_eq!(e.header_line, 4);
        assert_eq!(e.delimiter, b';');
        assert_eq!(e.unit, LengthUnit::Mm);
        assert_eq!(e.ignored_columns, vec!["RMS".to_string()]);
        assert_eq!(
            e.points[0],
            ExportPoint {
                line: 5,
                id: "P001".into(),
                xy_mm: [212.132, 0.5],
                z_mm: Some(10.001)
            }
        );
        assert_eq!(e.points[1].line, 6);
        assert!(
            e.notes
                .iter()
                .any(|n| n.contains("3 line(s) before the header")),
            "{:?}",
            e.notes
        );
        assert!(
            e.notes.iter().any(|n| n.contains("columns ignored: RMS")),
            "{:?}",
            e.notes
        );
    }

    #[test]
    fn metres_tabs_and_quotes() {
        let text = "\"Name\"\t\"X_m\"\t\"Y_m\"\n\"7\"\t0.212132\t-0.0005\n";
        let e = parse_export(text, &map("id=Name,x=X_m,y=Y_m"), None).unwrap();
        assert_eq!(e.unit, LengthUnit::M);
        assert_eq!(e.points[0].id, "7");
        assert!(
            (e.points[0].xy_mm[0] - 212.132).abs() < 1e-9
                && (e.points[0].xy_mm[1] + 0.5).abs() < 1e-12
        );
        // No unit in the header: as given.
        let e = parse_export(
            "Name,X,Y\nA1,0.2,0.1\n",
            &map("id=Name,x=X,y=Y"),
            Some(LengthUnit::M),
        )
        .unwrap();
        assert_eq!(e.points[0].xy_mm, [200.0, 100.0]);
    }

    #[test]
    fn decimal_commas_a_byte_order_mark_and_crlf() {
        let m = map("id=Punkt,x=X,y=Y");
        let text = "\u{feff}Punkt;X;Y;\r\nP1;212,132;-0,5;\r\n";
        let format = ExportFormat {
            unit: None,
            decimal_comma: true,
            workspace_extent_mm: None,
        };
        let e = parse_export_with(text, &m, format).unwrap();
        assert_eq!(e.points[0].xy_mm, [212.132, -0.5]);
        assert!(e.ignored_columns.is_empty(), "{:?}", e.ignored_columns);
        let err = parse_export(text, &m, None).unwrap_err().to_string();
        assert!(err.contains("line 2: 'X' = '212,132' is not a number (a decimal comma? write a point), or read the file with decimal commas"), "{err}");
        let err = parse_export_with("Punkt,X,Y\nP1,1,2\n", &m, format)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("comma-separated, so its numbers cannot have a decimal comma"),
            "{err}"
        );
    }

    #[test]
    fn errors_name_the_line_and_column() {
        let m = map("id=Point,x=X,y=Y,z=Z");
        for (text, unit, want) in [
            (
                "Point,X,Y\nP1,1,2\n",
                None,
                "names 'Z' but no line has it; the header looks like line 1: 'Point', 'X', 'Y'",
            ),
            (
                "point,X,Y,Z\nP1,1,2,3\n",
                None,
                "(names are exact: 'point' for 'Point'?)",
            ),
            (
                "Point,X,Y,Z\nP1,1,abc,3\n",
                None,
                "line 2: 'Y' = 'abc' is not a number",
            ),
            (
                "meta\nPoint,X,Y,Z\nP1,1,2,3\nP2,NaN,2,3\n",
                None,
                "line 4: 'X' = 'NaN' is not finite",
            ),
            (
                "Point,X,Y,Z\nP1,1,,3\n",
                None,
                "line 2: 'Y' is empty (point P1)",
            ),
            ("Point;X;Y;Z\nP1;1,5;2;3\n", None, "decimal comma"),
            (
                "Point,X,Y,Z\nP1,1,2\n",
                None,
                "line 2: 3 fields, the header (line 1) has 4",
            ),
            (
                "Point,X,Y,Z\n,1,2,3\n",
                None,
                "line 2: the point id ('Point') is empty",
            ),
            ("Point,X,Y,Z\n", None, "no points after the header"),
            (
                "Point,X,Y,Z\nP1,2e3,2,3\n",
                Some(LengthUnit::M),
                "line 2: 'X' = 2e3 m is absurd",
            ),
            (
                "Point,X,Y,Z,X\nP1,1,2,3,4\n",
                None,
                "column 'X' appears twice",
            ),
        ] {
            let e = parse_export(text, &m, unit).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
        let e = parse_export(
            "P,X [m],Y [mm]\n1,2,3\n",
            &map("id=P,x=X [m],y=Y [mm]"),
            None,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("the columns disagree on the unit"), "{e}");
        let e = parse_export(
            "P,X [m],Y [m]\n1,2,3\n",
            &map("id=P,x=X [m],y=Y [m]"),
            Some(LengthUnit::Mm),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("column 'X [m]' says m but the unit given is mm"),
            "{e}"
        );
    }
}
