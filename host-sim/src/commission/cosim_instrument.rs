//! The co-simulation's instrument: the plant's tool point through the instrument's frame,
//! scale and noise (`cosim::CoSim::instrument_reading_mm`), and the same point as a noiseless
//! instrument reads it (the truth the journey's accuracy is judged on, as the demo's).

use crate::cosim::CoSim;
use crate::plant::instrument::Instrument as PlantInstrument;
use crate::plant::PlantConfig;
use crate::session::instrument::Instrument;
use crate::session::{PointRequest, Reading, SessionError};

/// Reads the co-simulated plant (module doc).
pub struct CoSimInstrument<'a> {
    sim: &'a CoSim,
    /// The plant's instrument without noise: its frame and scale.
    noiseless: PlantInstrument,
    last_truth: Option<[f64; 2]>,
}

impl<'a> CoSimInstrument<'a> {
    /// The instrument of `sim`, whose plant is `plant`.
    pub fn new(sim: &'a CoSim, plant: &PlantConfig) -> Self {
        let mut cfg = plant.instrument.clone();
        cfg.noise_sigma_um = 0.0;
        CoSimInstrument {
            sim,
            noiseless: PlantInstrument::new(&cfg, 0),
            last_truth: None,
        }
    }
}

impl Instrument for CoSimInstrument<'_> {
    fn describe(&self) -> String {
        "the co-simulated plant's instrument (its frame, scale and noise)".into()
    }

    fn read(&mut self, point: &PointRequest) -> Result<Reading, SessionError> {
        let fail = |e: crate::cosim::CoSimError| SessionError::Reading {
            point: point.id.clone(),
            reason: format!("cannot be taken: {e}"),
        };
        let reading = self.sim.instrument_reading_mm().map_err(fail)?;
        let tool = self.sim.plant_truth().map_err(fail)?.tool_mm;
        self.last_truth = Some(self.noiseless.frame_mm(tool));
        Ok(Reading::Point(reading))
    }

    fn last_truth_mm(&self) -> Option<[f64; 2]> {
        self.last_truth
    }
}
