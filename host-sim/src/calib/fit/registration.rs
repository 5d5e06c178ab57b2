//! Every fit estimates the instrument's frame with the model (`crate::calib::frame` states the
//! convention that defines the machine frame and what is identifiable).
//!
//! How, by method:
//! * **a first frame** ([`register_with`] on the nominal model): the best rigid motion from the
//!   nominal model's tool points at the recorded angles to the readings (2-D Procrustes,
//!   `crate::numeric::rigid`), robust to blunders: rows beyond `4·median + 10 µm` of the
//!   previous pass are left out and the motion estimated again, until the set stops changing.
//!   The nominal model is 1-2 mm off a real machine, so this frame is right to about that; it
//!   takes the readings from metres away and any angle to near the machine, where the fits
//!   start from the nominal model;
//! * **`full`**: the LM fits A0, B0 and both encoder offsets, so in the first frame it absorbs
//!   what is left of the frame; [`registered_full`] moves that into the frame by the gauge
//!   (`calib::frame::machine_frame_gauge`, an exact change of frame: the residuals are the
//!   fit's), so the model's A0 and mean offset are the nominal's and the frame is the first one
//!   composed with the gauge's motion. Standard deviations are propagated through that change
//!   (first order, from the fit's covariance): A0 has none (the gauge fixes it), the encoder
//!   offsets share the one of their difference, the frame gets its own;
//! * **`poly`, `ls`** fit the links only (bases and offsets are the nominal's), so the frame
//!   must take the rest: [`register_dyads`] alternates the synthesis on the registered
//!   readings with [`register_with`] of the synthesised model, until the frame moves by less
//!   than 1e-10 rad and 1e-8 mm (at most [`MAX_DYAD_ROUNDS`]).
//!
//! Cost: a few FK sweeps over the data (the first frame), one per round for the dyads, 2·k
//! more for the propagation.

use super::full::FullFit;
use super::params::{from_vector, to_vector, N_PARAMS, STEP};
use crate::calib::frame::{machine_frame_gauge, InstrumentFrame};
use crate::calib::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::numeric::stats::median;
use crate::numeric::{procrustes, Rigid2};
use kinematics_core::FiveBar;
use nalgebra::DMatrix;

/// Whether a fit registers the instrument's frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FrameMode {
    /// The frame is estimated with the model (the module doc); the model is in the machine
    /// frame.
    #[default]
    Register,
    /// The readings are in the machine frame already (an instrument referenced to the machine,
    /// as the paper's was at Table I's point 1): used as they are, no frame is estimated.
    Machine,
}

/// At most this many rounds of synthesis and registration for `poly` and `ls`.
pub const MAX_DYAD_ROUNDS: usize = 200;
/// Passes of the robust registration's trimming.
const TRIM_PASSES: usize = 10;

/// The rigid motion (machine → instrument) that best takes `model`'s tool points at the
/// recorded angles onto the readings, robust to blunders (the module doc). Rows the model
/// cannot reach are left out; fewer than two usable rows, or rows all at one point, refuse.
pub fn register_with(model: &FiveBar<f64>, data: &[Measurement]) -> Result<Rigid2, CalibError> {
    let (pred, meas): (Vec<[f64; 2]>, Vec<[f64; 2]>) = data
        .iter()
        .filter_map(|m| Some((model.forward(m.theta_rad(), 0.0).ok()?, m.measured_mm)))
        .unzip();
    if pred.len() < 2 {
        return Err(invalid!(
            "the instrument's frame cannot be registered: {} of the {} poses are reachable by the model (check the angle columns: degrees, the encoders' zero)",
            pred.len(),
            data.len()
        ));
    }
    let none = || {
        invalid!(
            "the instrument's frame cannot be registered: the poses are all at one point (measure poses spread over the workspace)"
        )
    };
    let mut w = vec![1.0; pred.len()];
    let mut t = procrustes(&pred, &meas, None).ok_or_else(none)?;
    for _ in 0..TRIM_PASSES {
        let mut e: Vec<f64> = pred
            .iter()
            .zip(&meas)
            .map(|(p, q)| {
                let r = t.apply(*p);
                (r[0] - q[0]).hypot(r[1] - q[1])
            })
            .collect();
        let limit = 4.0 * median(&mut e.clone()).unwrap_or(0.0) + 0.01;
        let next: Vec<f64> = e
            .iter_mut()
            .map(|v| if *v <= limit { 1.0 } else { 0.0 })
            .collect();
        if next == w || 2.0 * next.iter().sum::<f64>() < pred.len() as f64 {
            break;
        }
        w = next;
        t = procrustes(&pred, &meas, Some(&w)).ok_or_else(none)?;
    }
    Ok(t)
}

/// The links-only syntheses (`poly`, `ls`) with the frame alternated in (the module doc):
/// `synth` fits a model to readings in the machine frame. Returns the model and the frame.
pub fn register_dyads(
    data: &[Measurement],
    start: Rigid2,
    mut synth: impl FnMut(&[Measurement]) -> Result<FiveBar<f64>, CalibError>,
) -> Result<(FiveBar<f64>, Rigid2), CalibError> {
    let mut t = start;
    let mut model = synth(&frame_of(t).register(data))?;
    for _ in 0..MAX_DYAD_ROUNDS {
        let next = register_with(&model, data)?;
        let moved = (next.rotation_rad - t.rotation_rad).abs() > 1e-10
            || (next.offset_mm[0] - t.offset_mm[0]).hypot(next.offset_mm[1] - t.offset_mm[1])
                > 1e-8;
        t = next;
        model = synth(&frame_of(t).register(data))?;
        if !moved {
            break;
        }
    }
    Ok((model, t))
}

fn frame_of(t: Rigid2) -> InstrumentFrame {
    InstrumentFrame {
        to_instrument: t,
        std_dev: None,
    }
}

/// A `full` fit made on readings registered by `first` (machine → instrument), moved into the
/// machine frame (the module doc): the machine-frame model, its standard deviations (A0 none)
/// and the frame with its own.
pub fn registered_full(
    f: &FullFit,
    nominal: &FiveBar<f64>,
    first: &Rigid2,
) -> (FiveBar<f64>, [Option<f64>; N_PARAMS], InstrumentFrame) {
    // The machine-frame parameters and the frame (rotation, offset x, y) of a fit's parameters.
    let map = |p: &[f64; N_PARAMS]| -> [f64; N_PARAMS + 3] {
        let (machine, g) = machine_frame_gauge(&from_vector(p, &f.model), nominal);
        let frame = first.after(&g);
        let mut out = [0.0; N_PARAMS + 3];
        out[..N_PARAMS].copy_from_slice(&to_vector(&machine));
        out[N_PARAMS] = frame.rotation_rad;
        out[N_PARAMS + 1] = frame.offset_mm[0];
        out[N_PARAMS + 2] = frame.offset_mm[1];
        out
    };
    let p0 = to_vector(&f.model);
    let q0 = map(&p0);
    let (machine, _) = machine_frame_gauge(&f.model, nominal);
    let frame_motion = Rigid2 {
        rotation_rad: q0[N_PARAMS],
        offset_mm: [q0[N_PARAMS + 1], q0[N_PARAMS + 2]],
    };
    // First-order propagation of the fit's covariance (free parameters) through the map,
    // central differences with the fit's own steps.
    let free = &f.lm.free;
    let cov = f.lm.covariance(f.lm.residual_variance());
    let mut j = DMatrix::<f64>::zeros(N_PARAMS + 3, free.len());
    for (c, &k) in free.iter().enumerate() {
        let (mut hi, mut lo) = (p0, p0);
        hi[k] += STEP[k];
        lo[k] -= STEP[k];
        let (a, b) = (map(&hi), map(&lo));
        for r in 0..N_PARAMS + 3 {
            j[(r, c)] = (a[r] - b[r]) / (2.0 * STEP[k]);
        }
    }
    let sq = &j * cov * j.transpose();
    let sd = |r: usize| sq[(r, r)].max(0.0).sqrt();
    let mut std_dev = [None; N_PARAMS];
    for (k, s) in std_dev.iter_mut().enumerate() {
        // A0 is the gauge's (fixed by convention); a parameter the fit held and the change of
        // frame does not move keeps none.
        if k < 8 && (f.std_dev[k].is_some() || sq[(k, k)] > 0.0) {
            *s = Some(sd(k));
        }
    }
    let frame = InstrumentFrame {
        to_instrument: frame_motion,
        std_dev: Some([sd(N_PARAMS), sd(N_PARAMS + 1), sd(N_PARAMS + 2)]),
    };
    (machine, std_dev, frame)
}
