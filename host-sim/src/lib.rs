//! `host-sim`: the real machine in simulation and the calibration tools around it.
//!
//! The same `kinematics-core` the firmware runs is linked here; this crate adds what only a host
//! needs: the plant (the overconstrained six-bar with its imperfections), the closed 2 kHz loop,
//! measurement protocols, the hidden-robot fits, the correction-grid builder, accuracy
//! statistics and the diagnosis of model/measurement disagreement.
//!
//! File formats (contracts other tools rely on): [`measurement_csv`], [`model_file`], the grid
//! image (`kinematics_core::grid`).
// `!(x >= lo)` instead of `x < lo` is deliberate throughout: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod diagnose;
pub mod io;
pub mod plant;
pub mod measure;
pub mod trajectory;
pub mod closed_loop;
pub mod simulate;
pub mod fit;
pub mod grid_build;
pub mod command;
pub mod accuracy;
pub mod machine;
pub mod numeric;
pub mod demo;
