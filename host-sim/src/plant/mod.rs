//! The simulated machine: linkage ([`sixbar`]), drives ([`drive`]), measuring instrument
//! ([`instrument`]) and their description ([`config`]), put together in [`Plant`].

pub mod config;
pub mod drive;
pub mod instrument;
pub mod sixbar;

pub use config::{Effect, PlantConfig, PlantModel};
pub use drive::Drive;
pub use instrument::Instrument;
pub use sixbar::{SixBar, SixBarSolution};

use anyhow::Result;

/// A plant with its state: what `measure` and `simulate` run against.
#[derive(Clone, Debug)]
pub struct Plant {
    pub config: PlantConfig,
    pub sixbar: SixBar,
    pub drives: [Drive; 2],
    pub instrument: Instrument,
}

impl Plant {
    /// Builds a plant; `seed` seeds the instrument noise.
    pub fn new(config: &PlantConfig, seed: u64) -> Self {
        Plant {
            config: config.clone(),
            sixbar: SixBar::new(&config.sixbar),
            drives: [Drive::new(&config.drive_1), Drive::new(&config.drive_2)],
            instrument: Instrument::new(&config.instrument, seed),
        }
    }

    /// Current geometric link angles.
    pub fn link_rad(&self) -> [f64; 2] {
        [self.drives[0].link_rad(), self.drives[1].link_rad()]
    }

    /// Current encoder readings.
    pub fn encoder_rad(&self) -> [f64; 2] {
        [self.drives[0].encoder_rad(), self.drives[1].encoder_rad()]
    }

    /// Quasi-static positioning: the servo holds each encoder at the count nearest to
    /// `encoder_rad`, having approached it in direction `dir`. Returns the encoder readings and
    /// the linkage's equilibrium.
    pub fn settle(&mut self, encoder_rad: [f64; 2], dir: [i8; 2]) -> Result<([f64; 2], SixBarSolution)> {
        let r = [self.drives[0].settle(encoder_rad[0], dir[0]), self.drives[1].settle(encoder_rad[1], dir[1])];
        let sol = self.sixbar.solve(self.link_rad())?;
        Ok((r, sol))
    }

    /// The linkage's equilibrium at the current link angles.
    pub fn solve(&mut self) -> Result<SixBarSolution> {
        let l = self.link_rad();
        self.sixbar.solve(l)
    }
}
