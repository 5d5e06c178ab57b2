//! Calibration: what a machine builder does with a new machine, as library functions.
//!
//! The stages, in the order a calibration runs them:
//! * [`protocol`]: the paper's measurement protocols as lists of visits (where to go, where the
//!   motion comes from);
//! * [`plan`]: the session's target lists (identification poses chosen for identifiability,
//!   grid nodes, verification targets, repeat runs), each row with its approach;
//! * [`machine`]: the machine being calibrated, behind one trait (the six-bar plant, or a
//!   stand-in five-bar);
//! * [`measure`]: THE measurement path: command every visit exactly as the firmware does, settle,
//!   read the instrument. `host-sim measure`, the demo and the tests all measure through it;
//! * [`fit`]: the hidden robot from measurements (the paper's `poly` and `ls`, the full LM),
//!   the instrument's frame registered with it;
//! * [`frame`]: the instrument's frame (where the tracker stands), the convention that defines
//!   the machine frame, the readings mapped into it;
//! * [`grid`]: the correction grid flash image from measurements at the nodes;
//! * [`image`]: the image finished with the machine's extension blocks (the workspace);
//! * [`command`]: motor angles for targets, exactly as the firmware computes them;
//! * [`backlash`]: the direction-dependent correction of backlash (command, grid, estimate);
//! * [`accuracy`]: VDI/DGQ 3441 and ISO 230-2 figures from repeated runs;
//! * [`dynamics`]: the hidden robot's dynamic parameters from a closed-loop excitation run
//!   (what the servo feeds forward);
//! * [`import`]: a real instrument's export (a laser tracker's points, by id) joined with the
//!   commanded list into the measurement CSV (`host-sim import`);
//! * [`pipeline`]: all of it on one machine, as `host-sim demo` runs it.
//! * [`verify`]: the accuracy report for the customer (the standards' figures and the 2-D
//!   position error, before and after calibration), from the verification and repeat runs.
//!
//! Where a change goes: a new protocol in `protocol.rs` (and `Protocol::parse`); a new fit
//! method in `fit/` (one file, wired in `fit/mod.rs`); a new accuracy figure in `accuracy.rs`;
//! a change to the demo's story in `pipeline/`. Machine constants come from the
//! [`MachineSpec`](crate::machine_spec::MachineSpec) in each options struct, never from here.

pub mod accuracy;
pub mod backlash;
pub mod command;
pub mod dynamics;
pub mod fit;
pub mod frame;
pub mod grid;
pub mod image;
pub mod import;
pub mod machine;
pub mod measure;
pub mod pipeline;
pub mod plan;
pub mod protocol;
pub mod verify;

use crate::io::IoError;
use crate::plant::PlantError;

/// Why a calibration step could not run. Every message is complete (the cause's text included).
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error(transparent)]
    Plant(#[from] PlantError),
    /// Input that cannot be used (bad data, impossible options); the message says which and
    /// names the line, node or point where there is one.
    #[error("{0}")]
    Invalid(String),
    /// The paper criterion compares with the targets, and this row (file line) has none.
    #[error("line {line}: the paper criterion needs x_target_mm,y_target_mm on every row")]
    MissingTargets { line: usize },
    /// A target that cannot be commanded or measured.
    #[error("target ({:.3}, {:.3}) mm: {reason}", target_mm[0], target_mm[1])]
    Target { target_mm: [f64; 2], reason: String },
    /// A failure inside a named step.
    #[error("{context}: {reason}")]
    Context { context: String, reason: String },
}

impl CalibError {
    /// This error as the cause of a failure in `context`.
    pub fn context(self, context: impl Into<String>) -> CalibError {
        CalibError::Context {
            context: context.into(),
            reason: self.to_string(),
        }
    }
}

/// A shorthand for [`CalibError::Invalid`] with a formatted message.
macro_rules! invalid {
    ($($t:tt)*) => { $crate::calib::CalibError::Invalid(format!($($t)*)) };
}
pub(crate) use invalid;
