//! The simulated machine: linkage ([`sixbar`] for its equilibrium and tool point, [`linkage`]
//! for its bodies' inertia), drives ([`drive`]), their coupled equations of motion
//! ([`motion`]), measuring instrument ([`instrument`]) and their description ([`config`]), put
//! together in [`Plant`].

pub mod config;
pub mod drive;
pub mod instrument;
pub mod linkage;
pub mod motion;
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
    /// The linkage's bodies (its inertia), on the six-bar's equivalent five-bar.
    pub linkage: linkage::Linkage,
    pub drives: [Drive; 2],
    pub instrument: Instrument,
}

impl Plant {
    /// Builds a plant; `seed` seeds the instrument noise.
    pub fn new(config: &PlantConfig, seed: u64) -> Self {
        let sixbar = SixBar::new(&config.sixbar);
        let linkage = linkage::Linkage::new(&config.linkage, sixbar.equivalent_five_bar(), &config.sixbar);
        Plant {
            config: config.clone(),
            sixbar,
            linkage,
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

    /// Advances the machine by `dt_s` (in `substeps` steps) under the joint torque commands
    /// `torque_nm`: the drives coupled through the linkage's inertia ([`motion`]).
    pub fn advance(&mut self, torque_nm: [f64; 2], dt_s: f64, substeps: u32) -> Result<()> {
        motion::CoupledDrives { drives: &mut self.drives, linkage: &self.linkage }
            .advance(torque_nm, dt_s, substeps)
            .map_err(|e| anyhow::anyhow!("plant dynamics at link angles {:?} rad: {e}", self.link_rad()))
    }

    /// The hidden robot's dynamic parameters of this machine's bodies and rotors, friction
    /// included: the truth an identification should find (up to the hidden robot's geometry).
    pub fn true_dynamics(&self) -> kinematics_core::FiveBarDynamics<f64> {
        let mut d = self.linkage.lumped();
        for k in 0..2 {
            d.motor_inertia_kg_m2[k] += self.drives[k].rotor_inertia_kg_m2();
            (d.viscous_nm_s_per_rad[k], d.coulomb_nm[k]) = self.drives[k].friction();
        }
        d
    }

    /// The linkage's equilibrium at the current link angles.
    pub fn solve(&mut self) -> Result<SixBarSolution> {
        let l = self.link_rad();
        self.sixbar.solve(l)
    }
}
