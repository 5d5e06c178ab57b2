//! The simulated machine: linkage ([`sixbar`]), drives ([`drive`]), measuring instrument
//! ([`instrument`]) and their description ([`config`]).

pub mod config;
pub mod sixbar;

pub use config::{Effect, PlantConfig, PlantModel};
pub use sixbar::{SixBar, SixBarSolution};
