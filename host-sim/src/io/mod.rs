//! Files: the formats other tools rely on, and writing them safely.
//!
//! * [`measurement_csv`]: the measurement CSV, the contract between measuring (an
//!   interferometer or `host-sim measure`) and every tool that reads measurements;
//! * [`model_file`]: `model.json`, a fitted hidden robot;
//! * [`dynamics_file`]: `dynamics.json`, its identified dynamic parameters;
//! * [`knots_csv`]: a streamed trajectory's knots (what `link stream --file` sends);
//! * [`telemetry_csv`]: the telemetry CSV, what the controller (and the host loop) reports of
//!   a motion: `identify` and `diagnose --telemetry` read it;
//! * [`targets_csv`]: the `x_mm,y_mm` target lists `command` reads, and the plan's lists;
//! * [`commanded_csv`]: the commanded list (`command`'s angles.csv) an instrument's export is
//!   joined with;
//! * [`tracker_export`]: a laser tracker's / interferometer's point export, through a column map;
//! * [`machine_file`]: the machine file (TOML), what `--machine` reads;
//! * [`plot`]: the PNG plots (paths, error-vector fields);
//! * [`csv_dialect`]: what every CSV read shares (delimiter detection, number ranges);
//! * [`policy`]: the output policy every command declares its files to: no output onto an
//!   input or onto another output, decided before anything is read heavily or written;
//! * [`atomic`]: every output goes through it: a failed run never leaves a half-written file.
//! * [`verify_plot`]: the accuracy report's plots (error map, ISO 230-2 chart), as PNG bytes.
//!
//! Formats tied to one stage's own types live next to them (the grid node table in
//! `calib::grid`, the closed-loop log in `sim::simulate`); the grid flash image is
//! `kinematics_core::grid`. Where a change goes: a new column or key here, versioned when old
//! files would no longer read (see each format's module doc).
//!
//! Errors ([`IoError`]) carry the whole message, the cause's text included (`{e}` says
//! everything; `source()` is not used, so a chain printed with `{:#}` does not repeat it).

pub mod atomic;
pub mod commanded_csv;
pub mod csv_dialect;
pub mod declared;
pub mod dynamics_file;
pub mod knots_csv;
pub mod machine_file;
pub mod measurement_csv;
pub mod model_file;
pub mod plot;
pub mod policy;
pub mod targets_csv;
pub mod telemetry_csv;
pub mod text_source;
pub mod tracker_export;
pub mod verify_plot;

use std::path::{Path, PathBuf};

/// Why a file could not be read, parsed or written.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file could not be read.
    #[error("cannot read {}: {message}", path.display())]
    Read { path: PathBuf, message: String },
    /// The file's contents are not what the format says (`message` names the line or key).
    #[error("in {}: {message}", path.display())]
    Content { path: PathBuf, message: String },
    /// Text (not from a file) is not what the format says.
    #[error("{0}")]
    Parse(String),
    /// The file is not of the expected kind at all.
    #[error("{} is not a valid {what}: {message}", path.display())]
    NotA {
        path: PathBuf,
        what: &'static str,
        message: String,
    },
    /// Data that must not be written (e.g. an invalid model).
    #[error("{0}")]
    Invalid(String),
    /// The output directory could not be created.
    #[error("cannot create directory {}: {message}", dir.display())]
    CreateDir { dir: PathBuf, message: String },
    /// An output is an input or another output, or a file is given twice (`policy`); the
    /// message names both flags.
    #[error("{0}")]
    Clash(String),
    /// The output path names a directory, not a file.
    #[error("output path has no file name")]
    NoFileName { path: PathBuf },
    /// The file could not be written (nothing was left behind).
    #[error("cannot write {}: {message}", path.display())]
    Write { path: PathBuf, message: String },
    /// A plot could not be drawn.
    #[error("plot: {0}")]
    Plot(String),
}

impl IoError {
    /// A read error of `path` from any displayable cause.
    pub fn read(path: &Path, cause: impl std::fmt::Display) -> Self {
        IoError::Read {
            path: path.to_path_buf(),
            message: cause.to_string(),
        }
    }

    /// A format error of the text read from `path`.
    pub fn content(path: &Path, cause: impl std::fmt::Display) -> Self {
        IoError::Content {
            path: path.to_path_buf(),
            message: cause.to_string(),
        }
    }
}

/// Reads a whole text file of a format the tools define: UTF-8 (a byte-order mark dropped);
/// other encodings are refused naming the line and what the file looks like
/// (`text_source::not_utf8`).
pub fn read_text(path: &Path) -> Result<String, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::read(path, e))?;
    let body = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
    match std::str::from_utf8(body) {
        Ok(s) => Ok(s.to_string()),
        Err(e) => Err(IoError::content(path, text_source::not_utf8(body, &e))),
    }
}

/// Reads a whole binary file (a grid image).
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, IoError> {
    std::fs::read(path).map_err(|e| IoError::read(path, e))
}

/// The `format` and `version` fields of a JSON file the tools define, checked: `what` names
/// the kind of file ("model", "dynamics") in the error, `expected` is its `format` value and
/// `supported` the one version this host-sim reads.
pub(crate) fn check_format(
    what: &str,
    format: &str,
    expected: &str,
    version: u32,
    supported: u32,
) -> Result<(), IoError> {
    if format != expected {
        return Err(IoError::Invalid(format!(
            "not a {what} file: format is '{format}', expected '{expected}'"
        )));
    }
    if version != supported {
        return Err(IoError::Invalid(format!(
            "unsupported {what} file version {version}"
        )));
    }
    Ok(())
}

/// How [`json_text`] orders the keys of a struct.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyOrder {
    /// As the struct declares its fields (`model.json`).
    Declared,
    /// Sorted (every report the commands print or write: stable whatever the struct's order).
    Sorted,
}

/// Pretty JSON with a final newline: how every JSON file and report of the tools is written.
pub fn json_text(value: &impl serde::Serialize, order: KeyOrder) -> Result<String, IoError> {
    let err = |e: serde_json::Error| IoError::Invalid(format!("cannot serialize: {e}"));
    let mut text = match order {
        KeyOrder::Declared => serde_json::to_string_pretty(value).map_err(err)?,
        // A `Value`'s objects are ordered maps.
        KeyOrder::Sorted => {
            serde_json::to_string_pretty(&serde_json::to_value(value).map_err(err)?).map_err(err)?
        }
    };
    text.push('\n');
    Ok(text)
}
