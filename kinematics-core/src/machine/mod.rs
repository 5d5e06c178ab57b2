//! The machine the controller drives, and the judgements of a calibration image against it.
//!
//! * [`record`]: [`MachineRecord`], the machine in one value (name, nominal model, encoder
//!   convention, workspace, home, plausibility limits), its canonical encoding and its
//!   [`MachineRecord::digest`], the identity of its geometry. The calibration image carries it
//!   as its `HRMC` block ([`crate::grid::CorrectionGrid::machine`]).
//! * [`same_machine`]: whether a model is one of this machine, by the tool positions over the
//!   workspace in the best-fitting rigid frame (so the instrument's frame is free).
//! * [`plausible`]: whether an image's content is what a calibration of this machine can
//!   need: node corrections, their slope between neighbours, dynamics, backlash, workspace.
//! * [`judge_image`]: both, as the controller runs them at commit and boot and the host tools
//!   before they write or use an image.
//!
//! f32, no heap: the judgements run on the MCU (cost in each module's doc).
//!
//! # Example
//! ```
//! use kinematics_core::grid::{append_machine, encode, CorrectionGrid};
//! use kinematics_core::machine::{judge_image, ImageRefusal, MachineRecord};
//! use kinematics_core::paper;
//!
//! let machine = MachineRecord::paper();
//! let geometry = paper::grid_geometry();
//! let mut image = vec![0u8; geometry.image_len() + kinematics_core::grid::MACHINE_LEN];
//! let n = encode(&mut image, &geometry, &machine.nominal, &vec![[1e-4, -1e-4]; geometry.len()])
//!     .unwrap();
//! let end = append_machine(&mut image, n, n, &machine).unwrap();
//! let grid = CorrectionGrid::parse(&image[..end]).unwrap();
//! assert_eq!(grid.machine().unwrap().digest(), machine.digest());
//! let verdict = judge_image(&grid, &machine).unwrap();
//! assert!(verdict.same.worst_mm < 1e-3);
//!
//! // Another design: links 10 mm longer. Refused, naming the deviation.
//! let mut other = machine;
//! other.nominal.b_mm = 160.0;
//! let mut image2 = vec![0u8; geometry.image_len()];
//! encode(&mut image2, &geometry, &other.nominal, &vec![[0.0; 2]; geometry.len()]).unwrap();
//! let grid2 = CorrectionGrid::parse(&image2).unwrap();
//! let refusal = judge_image(&grid2, &machine).unwrap_err();
//! assert!(matches!(refusal, ImageRefusal::OtherMachine(_)));
//! assert!(refusal.to_string().contains("b_mm explains it: image 160.0000, controller 150.0000"));
//! ```

mod judge;
mod lattice;
mod plausible;
pub mod record;
mod refusal;
mod same;

pub use judge::{judge_image, Verdict};
pub use lattice::{LATTICE_PER_AXIS, MAX_POINTS};
pub use plausible::{plausible, Margins, WORKSPACE_TOLERANCE_MM};
pub use record::{MachineName, MachineRecord, PlausibilityLimits, RecordError};
pub use refusal::{
    ImageRefusal, Implausible, MachineMismatch, ModelParameter, ParameterDifference,
};
pub use same::{best_rigid_fit, same_machine, RigidFrame, SameMachine};
