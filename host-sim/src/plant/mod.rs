//! The simulated machine: the gantry that carries the micro on a redundant machine
//! ([`gantry`]: its axes and drives); the micro's linkage ([`sixbar`] for its equilibrium and tool point, [`linkage`]
//! for its bodies' inertia), drives ([`drive`]), their coupled equations of motion
//! ([`motion`]), measuring instrument ([`instrument`]) and their description ([`config`], the
//! plant TOML), put together in [`Plant`].
//!
//! Where a change goes: a new physical effect of the machine is a parameter in `config.rs`
//! (with its TOML key, its unit in the name, 0 = off, and its entry in `PlantConfig::with_only`)
//! and its physics in the file of the part it belongs to; `PLANT.md` describes them.

pub mod config;
pub mod drive;
pub mod gantry;
pub mod instrument;
pub mod linkage;
pub mod motion;
pub mod sixbar;

pub use config::{PlantConfig, PlantModel};
pub use drive::Drive;
pub use instrument::Instrument;
pub use sixbar::{SixBar, SixBarSolution};

/// Why a plant cannot be built or solved.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PlantError {
    /// Not `ideal`, `paper` or an existing file.
    #[error("unknown plant '{0}': not 'ideal', 'paper' or an existing TOML file")]
    UnknownPlant(String),
    /// The plant file could not be read.
    #[error("cannot read plant file {path}: {message}")]
    Read { path: String, message: String },
    /// The plant file is not a valid description (`message` says why).
    #[error("in plant file {path}: {message}")]
    InFile { path: String, message: String },
    /// Not TOML of the plant description's shape (unknown or misspelt keys included).
    #[error("not a valid plant description: {0}")]
    Toml(String),
    /// A value that is not a machine (non-finite, negative, absurd); the message names the key.
    #[error("{0}")]
    Invalid(String),
    /// The linkage cannot be assembled at these link angles.
    #[error("link angles ({:.4}°, {:.4}°) not assemblable: {reason}", link_deg[0], link_deg[1])]
    NotAssemblable { link_deg: [f64; 2], reason: String },
    /// The six-bar's stiffness matrix is singular.
    #[error("six-bar equilibrium: singular stiffness at link angles ({:.4}°, {:.4}°)", link_deg[0], link_deg[1])]
    SingularStiffness { link_deg: [f64; 2] },
    /// `with_only` of an effect the plant has no setting of its own for.
    #[error(
        "the plant has no separate setting for {0} (it is part of link_geometry, or not modelled)"
    )]
    NoSetting(crate::effect::PhysicalEffect),
    /// The equilibrium solve did not converge.
    #[error(
        "six-bar equilibrium did not converge in {iterations} iterations at link angles ({:.4}°, {:.4}°)",
        link_deg[0],
        link_deg[1]
    )]
    NotConverged { link_deg: [f64; 2], iterations: u32 },
}

/// Link angles in degrees, for messages.
pub(crate) fn deg(link_rad: [f64; 2]) -> [f64; 2] {
    [link_rad[0].to_degrees(), link_rad[1].to_degrees()]
}

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
        let linkage = linkage::Linkage::new(
            &config.linkage,
            sixbar.equivalent_five_bar(),
            &config.sixbar,
        );
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
    pub fn settle(
        &mut self,
        encoder_rad: [f64; 2],
        dir: [i8; 2],
    ) -> Result<([f64; 2], SixBarSolution), PlantError> {
        let r = [
            self.drives[0].settle(encoder_rad[0], dir[0]),
            self.drives[1].settle(encoder_rad[1], dir[1]),
        ];
        let sol = self.sixbar.solve(self.link_rad())?;
        Ok((r, sol))
    }

    /// Advances the machine by `dt_s` (in `substeps` steps) under the joint torque commands
    /// `torque_nm`: the drives coupled through the linkage's inertia ([`motion`]).
    pub fn advance(
        &mut self,
        torque_nm: [f64; 2],
        dt_s: f64,
        substeps: u32,
    ) -> Result<(), PlantError> {
        motion::CoupledDrives {
            drives: &mut self.drives,
            linkage: &self.linkage,
        }
        .advance(torque_nm, dt_s, substeps)
        .map_err(|e| PlantError::NotAssemblable {
            link_deg: deg(self.link_rad()),
            reason: e.to_string(),
        })
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
    pub fn solve(&mut self) -> Result<SixBarSolution, PlantError> {
        let l = self.link_rad();
        self.sixbar.solve(l)
    }
}
