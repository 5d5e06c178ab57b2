//! The instrument's frame: where the laser tracker (or interferometer) stands against the
//! machine, registered by the fit and applied to every later reading of the same set-up.
//!
//! Why: a tracker stands anywhere in the room, metres away and at any angle. Its readings are
//! the tool points moved by a rigid motion `reading = R(φ)·machine + t`. A model fitted in the
//! instrument's frame carries that motion in its base point and encoder offsets: far from the
//! nominal, so the controller refuses it, and commands in the machine frame land metres off.
//! So every fit estimates the motion with the model ([`super::fit::registration`]), returns the
//! model in the MACHINE frame, and stores the motion in `model.json` (`instrument_frame`);
//! `grid`, `measure --model`, `verify --model`, `accuracy --model`, `diagnose --model` and the
//! demo map the readings into the machine frame with it ([`InstrumentFrame::register`]).
//!
//! **The gauge.** A rigid motion of the instrument's frame changes the readings exactly as the
//! same motion of the whole machine does: a shift is a common shift of both bases A0 and B0, a
//! rotation by φ turns both bases about the origin and adds φ to both encoder offsets. The
//! readings cannot tell the two apart: of the five-bar's ten parameters and the frame's three,
//! only ten combinations are identified (the four links, B0 − A0 in the encoders' frame, i.e.
//! its length and its direction against encoder 1's zero, and the difference of the encoder
//! offsets; then, by convention, the frame). The convention that defines the machine frame
//! ([`machine_frame_gauge`]):
//!
//! * **origin**: A0 is at its nominal position (the machine file's `a0_mm`): the shift of the
//!   instrument and a common shift of the bases are one, and it is put in the frame;
//! * **orientation**: the mean of the two encoder offsets is the nominal mean, i.e. the
//!   machine's x axis is where the two motors' homing zeros (index marks) put it on average:
//!   a common rotation of the bases and the offsets and a rotation of the instrument are one,
//!   and it is put in the frame.
//!
//! So a registered model has A0 = nominal and mean offset = nominal exactly, and its other
//! parameters (links, B0 − A0, the offsets' difference) are what the data determine; its
//! commands put the tool where the targets are in that frame, near the nominal one (the
//! controller's workspace, stops and homing are in it). What is NOT identifiable, by any
//! instrument without references on the machine: where the physical A0 bearing sits, and the
//! common part of the encoder offsets; a machine whose A0 is 0.1 mm off its drawing calibrates
//! to a frame 0.1 mm off the drawing's, with every tool position right in it.
//!
//! Cost: one rotation and shift per reading.

use crate::io::measurement_csv::Measurement;
use crate::io::model_file::{FrameRecord, ModelFile};
use crate::io::IoError;
use crate::numeric::{round6, Rigid2};
use kinematics_core::FiveBar;
use serde::Serialize;
use std::collections::BTreeMap;

/// What the convention of the module doc says, as files and reports state it.
pub const CONVENTION: &str = "reading = offset_mm + R(rotation_deg)·machine; machine frame: A0 at its nominal position, mean of the encoder offsets at the nominal mean";

/// The registered frame of one instrument set-up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstrumentFrame {
    /// Machine → instrument: `reading = R·machine + offset`.
    pub to_instrument: Rigid2,
    /// One standard deviation of (rotation rad, offset x mm, offset y mm), when the fit
    /// estimated them.
    pub std_dev: Option<[f64; 3]>,
}

impl InstrumentFrame {
    /// The instrument's frame is the machine's.
    pub const IDENTITY: InstrumentFrame = InstrumentFrame {
        to_instrument: Rigid2::IDENTITY,
        std_dev: None,
    };

    /// A reading in the machine frame.
    pub fn to_machine_mm(&self, reading_mm: [f64; 2]) -> [f64; 2] {
        self.to_instrument.inverse().apply(reading_mm)
    }

    /// A machine-frame point as the instrument reads it.
    pub fn to_instrument_mm(&self, machine_mm: [f64; 2]) -> [f64; 2] {
        self.to_instrument.apply(machine_mm)
    }

    /// The rows with their readings in the machine frame (everything else as it was).
    pub fn register(&self, rows: &[Measurement]) -> Vec<Measurement> {
        let back = self.to_instrument.inverse();
        rows.iter()
            .map(|m| Measurement {
                measured_mm: back.apply(m.measured_mm),
                ..m.clone()
            })
            .collect()
    }

    /// The record `model.json` stores.
    pub fn record(&self) -> FrameRecord {
        let mut std_dev = BTreeMap::new();
        if let Some([r, x, y]) = self.std_dev {
            std_dev.insert("rotation_deg".to_string(), r.to_degrees());
            std_dev.insert("offset_x_mm".to_string(), x);
            std_dev.insert("offset_y_mm".to_string(), y);
        }
        FrameRecord {
            rotation_deg: self.to_instrument.rotation_rad.to_degrees(),
            offset_mm: self.to_instrument.offset_mm,
            std_dev,
            convention: Some(CONVENTION.to_string()),
        }
    }

    /// The instrument frame a model file's readings are registered by: the stored one, or the
    /// identity for a file without one (its model is in the instrument's frame).
    pub fn of_model_file(file: &ModelFile) -> Result<InstrumentFrame, IoError> {
        match &file.instrument_frame {
            Some(r) => {
                r.check()?;
                Ok(InstrumentFrame::from_record(r))
            }
            None => Ok(InstrumentFrame::IDENTITY),
        }
    }

    /// The frame of a stored record (checked by the model file's reader).
    pub fn from_record(r: &FrameRecord) -> InstrumentFrame {
        let sd = |k: &str| r.std_dev.get(k).copied();
        let std_dev = match (sd("rotation_deg"), sd("offset_x_mm"), sd("offset_y_mm")) {
            (Some(a), Some(x), Some(y)) => Some([a.to_radians(), x, y]),
            _ => None,
        };
        InstrumentFrame {
            to_instrument: Rigid2 {
                rotation_rad: r.rotation_deg.to_radians(),
                offset_mm: r.offset_mm,
            },
            std_dev,
        }
    }

    /// The figures reports print.
    pub fn summary(&self) -> FrameSummary {
        FrameSummary {
            rotation_deg: round6(self.to_instrument.rotation_rad.to_degrees()),
            offset_mm: self.to_instrument.offset_mm.map(round6),
            std_dev_rotation_deg: self.std_dev.map(|s| round6(s[0].to_degrees())),
            std_dev_offset_mm: self.std_dev.map(|s| [round6(s[1]), round6(s[2])]),
            convention: CONVENTION,
        }
    }
}

/// The registration as reports print it (`fit`'s and `demo`'s JSON: `instrument_frame`).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct FrameSummary {
    pub rotation_deg: f64,
    pub offset_mm: [f64; 2],
    #[serde(skip_serializing_if = "Option::is_none")]
    pub std_dev_rotation_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub std_dev_offset_mm: Option<[f64; 2]>,
    pub convention: &'static str,
}

/// The machine-frame model equivalent to `model` (a five-bar in some other frame) under the
/// convention of the module doc, and the motion `G` from the machine frame to `model`'s:
/// `model.forward(θ) = G(machine.forward(θ))` for every θ. With `G = R(ψ)·p + s`:
/// ψ = mean(offsets) − mean(nominal offsets), the offsets less ψ, B0 − A0 turned by −ψ,
/// A0 = the nominal's, s = A0 − R(ψ)·A0_nominal. Links and working mode are unchanged.
pub fn machine_frame_gauge(model: &FiveBar<f64>, nominal: &FiveBar<f64>) -> (FiveBar<f64>, Rigid2) {
    let mean = |m: &FiveBar<f64>| 0.5 * (m.encoder_offset_rad[0] + m.encoder_offset_rad[1]);
    let psi = mean(model) - mean(nominal);
    let turn = Rigid2 {
        rotation_rad: psi,
        offset_mm: [0.0, 0.0],
    };
    let r_a0 = turn.rotate(nominal.base_a0_mm);
    let g = Rigid2 {
        rotation_rad: psi,
        offset_mm: [model.base_a0_mm[0] - r_a0[0], model.base_a0_mm[1] - r_a0[1]],
    };
    let machine = FiveBar {
        base_a0_mm: nominal.base_a0_mm,
        base_b0_mm: turn.inverse().rotate(model.base_b0_mm),
        encoder_offset_rad: model.encoder_offset_rad.map(|o| o - psi),
        ..*model
    };
    (machine, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gauge_is_an_exact_change_of_frame() {
        let mut nominal = FiveBar::<f64>::paper_nominal();
        nominal.base_a0_mm = [10.0, 20.0];
        nominal.base_b0_mm = [1.0, -0.5];
        nominal.encoder_offset_rad = [5f64.to_radians(), -8f64.to_radians()];
        // A model in a frame 3 m away and turned by 2 rad.
        let mut m = nominal;
        m.a_mm += 0.3;
        m.base_a0_mm = [3000.0, -1200.0];
        m.base_b0_mm = [0.4, 1.1];
        m.encoder_offset_rad = [2.1, 1.9];
        let (machine, g) = machine_frame_gauge(&m, &nominal);
        assert_eq!(machine.base_a0_mm, nominal.base_a0_mm);
        let mean = |f: &FiveBar<f64>| f.encoder_offset_rad[0] + f.encoder_offset_rad[1];
        assert!((mean(&machine) - mean(&nominal)).abs() < 1e-12);
        for t in [[222.0, 20.0], [200.0, 60.0], [250.0, -40.0]] {
            let th = machine.inverse(t, 0.0).unwrap();
            let want = m.forward(th, 0.0).unwrap();
            let got = g.apply(machine.forward(th, 0.0).unwrap());
            assert!(
                (want[0] - got[0]).abs() < 1e-9 && (want[1] - got[1]).abs() < 1e-9,
                "{want:?} {got:?}"
            );
        }
        // A model already in the convention is its own machine-frame model.
        let (same, id) = machine_frame_gauge(&nominal, &nominal);
        assert_eq!(same.base_a0_mm, nominal.base_a0_mm);
        assert!(id.rotation_rad.abs() < 1e-15 && id.offset_mm.iter().all(|v| v.abs() < 1e-12));
    }

    #[test]
    fn a_record_round_trips() {
        let f = InstrumentFrame {
            to_instrument: Rigid2 {
                rotation_rad: 0.35f64.to_radians(),
                offset_mm: [2500.0, -12.5],
            },
            std_dev: Some([1e-6, 2e-4, 3e-4]),
        };
        let back = InstrumentFrame::from_record(&f.record());
        assert!((back.to_instrument.rotation_rad - f.to_instrument.rotation_rad).abs() < 1e-15);
        assert_eq!(back.to_instrument.offset_mm, f.to_instrument.offset_mm);
        let p = [212.0, 10.0];
        let q = f.to_machine_mm(f.to_instrument_mm(p));
        assert!((q[0] - p[0]).abs() < 1e-9 && (q[1] - p[1]).abs() < 1e-9);
    }
}
