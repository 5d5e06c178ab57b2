//! `host-sim`: the real machine in simulation and the calibration tools around it, as a library
//! of typed functions; the `host-sim` command line (`src/main.rs`, `src/cli/`) is a thin edge
//! over it.
//!
//! The same `kinematics-core` the firmware runs is linked here; this crate adds what only a host
//! needs. Folders name the stages (each module doc says what belongs there and where a change
//! goes):
//!
//! | module | what |
//! |---|---|
//! | [`machine_spec`] | the machine's constants, once: nominal model, workspace, grid lattice, servo rate |
//! | [`gantry_spec`] | the gantry that carries the micro on a redundant machine (`[gantry]`) |
//! | [`effect`] | the names of the physical effects, shared by the plant and the diagnosis |
//! | [`plant`] | the simulated six-bar with its imperfections (the "real machine") |
//! | [`loop_closure`] | the six-bar's loop closure linearised about a nominal five-bar (diagnosis and grid prior) |
//! | [`sim`] | trajectories and the closed 2 kHz loop |
//! | [`cut`] | the redundant machine cuts a part program: G-code, split planner, bound, execution |
//! | [`calib`] | protocols, the one measurement path, fits, grid, command, accuracy, the demo pipeline |
//! | [`diagnose`] | where model and measurements disagree, and which effect is missing |
//! | [`dynamics`] | the moving machine from telemetry: excitation, identification through the controller, diagnosis of the dynamics model |
//! | [`synth`] | measurements of machines with hidden effects, shared by the diagnosis' tests and studies |
//! | [`numeric`] | the one Levenberg–Marquardt, finite differences, column-scaled SVD, max/RMS |
//! | [`link`] | the controller's host link: client, streamed motion, calibration upload, telemetry |
//! | [`cosim`] | the production firmware under QEMU driving the plant in lockstep (co-simulation) |
//! | [`commission`] | the machine builder's whole journey through the controller, in one call |
//! | [`session`] | a measurement session through the controller: a plan's list visited, settled, read |
//! | [`io`] | file formats (measurement CSV, model file, targets, plots) and atomic output |
//!
//! Conventions: library functions take an options struct (with the [`machine_spec::MachineSpec`]
//! where machine constants are needed) and return typed results and typed errors (`thiserror`,
//! one enum per stage, every message complete); nothing in the library prints, parses flags or
//! uses `anyhow` (lints below). File formats are contracts other tools rely on:
//! [`io::measurement_csv`], [`io::model_file`], the grid image (`kinematics_core::grid`).
// `!(x >= lo)` instead of `x < lo` is deliberate throughout: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
#![forbid(unsafe_code)]
#![deny(rust_2018_idioms, unused_must_use, rustdoc::broken_intra_doc_links)]
// The library reports through its return values; the command line prints.
#![cfg_attr(
    not(test),
    deny(clippy::print_stdout, clippy::print_stderr, clippy::dbg_macro)
)]

pub mod calib;
pub mod commission;
pub mod cosim;
pub mod cut;
pub mod diagnose;
pub mod dynamics;
pub mod effect;
pub mod gantry_spec;
pub mod io;
pub mod link;
pub mod loop_closure;
pub mod machine_identity;
pub mod machine_spec;
/// The machine file's physical ranges (a part of [`machine_spec`], kept at its old path).
pub use machine_spec::ranges as machine_ranges;
pub mod numeric;
pub mod plant;
pub mod session;
pub mod sim;
pub mod synth;
