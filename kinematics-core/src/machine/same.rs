//! "Is this image's model a model of this machine?", judged by what the machine does, not
//! parameter by parameter.
//!
//! # The judgement
//! At each point `p` of the record's workspace lattice (`lattice`, up to 81 points) the
//! nominal's IK gives joint angles `θ(p)`; the image's model's FK at those angles gives
//! `q(p)`: where the image's model says the tool is when the controller commands this machine's
//! nominal pose for `p`. The best-fitting rigid transform (rotation and translation, closed-form
//! 2-D Procrustes, [`best_rigid_fit`]) takes the `q` onto the `p`; the largest remaining
//! distance is the deviation. The image is this machine's when the deviation is within the
//! record's `same_machine_tolerance_mm`.
//!
//! Why rigid-free: a calibration measures in its instrument's frame, and a laser tracker can
//! stand anywhere: a translation lands in the base A0, a rotation in A0, B0 and both encoder
//! offsets. Neither changes what the machine is. Lengths, the bases' distance and the offsets'
//! difference do, and they survive the fit: another design is centimetres off, a built machine
//! within about 1.5 mm of its drawing.
//!
//! When the deviation is beyond the tolerance, each of the ten parameters is in turn set back
//! to the nominal's value; if one alone brings the model within the tolerance, the refusal
//! names it with both values ([`super::ParameterDifference`]).
//!
//! # Cost
//! Per lattice point one IK and one FK (the Cortex-M4F's counts: 325 and 212 instructions) and
//! a few flops: about 45,000 instructions for 81 points (0.3 ms at 170 MHz). A refusal tries
//! ten more models: about 0.2 M instructions more. Run at an image's commit and at boot, never
//! in the servo's sample.

use super::lattice::{workspace_points, MAX_POINTS};
use super::record::MachineRecord;
use super::refusal::{MachineMismatch, ModelParameter, ParameterDifference};
use crate::model::FiveBar;
use crate::real::Real;

/// A rigid transform of the plane: `x ↦ R(θ)·x + t`, with `R` given by `(cos θ, sin θ)`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RigidFrame<T> {
    /// `(cos θ, sin θ)` of the rotation.
    pub cos_sin: [T; 2],
    /// The translation (mm).
    pub translation_mm: [T; 2],
}

impl<T: Real> RigidFrame<T> {
    /// The frame applied to `p`.
    pub fn apply(&self, p: [T; 2]) -> [T; 2] {
        let [c, s] = self.cos_sin;
        [
            c * p[0] - s * p[1] + self.translation_mm[0],
            s * p[0] + c * p[1] + self.translation_mm[1],
        ]
    }

    /// The rotation angle (rad).
    pub fn rotation_rad(&self) -> T {
        self.cos_sin[1].atan2(self.cos_sin[0])
    }
}

/// The rigid transform taking `from[k]` closest to `to[k]` in the least-squares sense (the 2-D
/// Procrustes problem without scale): with both sets centred, `θ = atan2(Σ u×v, Σ u·v)` and
/// the translation maps one centroid onto the other. `None` for fewer than one pair or
/// non-finite input. Cost: about 12 flops per pair and one square root.
pub fn best_rigid_fit<T: Real>(from: &[[T; 2]], to: &[[T; 2]]) -> Option<RigidFrame<T>> {
    let n = from.len().min(to.len());
    if n == 0 {
        return None;
    }
    let count = T::from_f64(n as f64);
    let mut cf = [T::ZERO; 2];
    let mut ct = [T::ZERO; 2];
    for (f, t) in from.iter().zip(to) {
        cf = [cf[0] + f[0], cf[1] + f[1]];
        ct = [ct[0] + t[0], ct[1] + t[1]];
    }
    cf = [cf[0] / count, cf[1] / count];
    ct = [ct[0] / count, ct[1] / count];
    let (mut dot, mut cross) = (T::ZERO, T::ZERO);
    for (f, t) in from.iter().zip(to) {
        let u = [f[0] - cf[0], f[1] - cf[1]];
        let v = [t[0] - ct[0], t[1] - ct[1]];
        dot = dot + u[0] * v[0] + u[1] * v[1];
        cross = cross + u[0] * v[1] - u[1] * v[0];
    }
    let norm = (dot * dot + cross * cross).sqrt();
    // A single point (or all coincident) leaves the rotation free: keep none.
    let cos_sin = if norm > T::ZERO {
        [dot / norm, cross / norm]
    } else {
        [T::ONE, T::ZERO]
    };
    let rotated = RigidFrame {
        cos_sin,
        translation_mm: [T::ZERO; 2],
    }
    .apply(cf);
    let frame = RigidFrame {
        cos_sin,
        translation_mm: [ct[0] - rotated[0], ct[1] - rotated[1]],
    };
    let finite = [
        cos_sin[0],
        cos_sin[1],
        frame.translation_mm[0],
        frame.translation_mm[1],
    ]
    .iter()
    .all(|v| v.is_finite());
    finite.then_some(frame)
}

/// What the judgement found for a model of this machine.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SameMachine {
    /// The largest tool-position difference from the nominal over the lattice (mm), in the
    /// best-fitting rigid frame.
    pub worst_mm: f32,
    /// Where (mm).
    pub at_mm: [f32; 2],
    /// The frame that takes the image's model's tool positions onto the nominal's: the
    /// instrument's frame as the calibration saw it.
    pub frame: RigidFrame<f32>,
    /// Lattice points judged.
    pub points: u16,
}

/// The nominal's joint angles at the lattice points it reaches (the record's workspace is
/// reachable by construction; a point it does not reach is left out).
struct Lattice {
    points: [[f32; 2]; MAX_POINTS],
    angles: [[f32; 2]; MAX_POINTS],
    len: usize,
}

impl Lattice {
    fn of(record: &MachineRecord) -> Lattice {
        let (all, n) = workspace_points(&record.workspace.region);
        let mut out = Lattice {
            points: [[0.0; 2]; MAX_POINTS],
            angles: [[0.0; 2]; MAX_POINTS],
            len: 0,
        };
        for p in &all[..n] {
            if let Ok(theta) = record.nominal.inverse(*p, 0.0) {
                out.points[out.len] = *p;
                out.angles[out.len] = theta;
                out.len += 1;
            }
        }
        out
    }

    /// The deviation of `model` (module doc), or the first point where it has no pose.
    fn deviation(&self, model: &FiveBar<f32>) -> Result<SameMachine, [f32; 2]> {
        let mut reached = [[0.0f32; 2]; MAX_POINTS];
        let n = self.len;
        for ((r, theta), p) in reached
            .iter_mut()
            .zip(&self.angles)
            .zip(&self.points)
            .take(n)
        {
            *r = model.forward(*theta, 0.0).map_err(|_| *p)?;
        }
        let first = self.points.first().copied().unwrap_or([0.0; 2]);
        let frame = best_rigid_fit(&reached[..n], &self.points[..n]).ok_or(first)?;
        let mut worst = SameMachine {
            worst_mm: 0.0,
            at_mm: first,
            frame,
            points: n as u16,
        };
        for (r, p) in reached.iter().zip(&self.points).take(n) {
            let (q, p) = (frame.apply(*r), *p);
            let d = Real::sqrt((q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1]));
            // `!(d <= worst)` also lets a NaN through to the refusal.
            if !(d <= worst.worst_mm) {
                worst.worst_mm = d;
                worst.at_mm = p;
            }
        }
        Ok(worst)
    }
}

/// Whether `model` is a model of `record`'s machine (module doc); the refusal names the worst
/// point and, where one parameter explains it, that parameter with both values.
pub fn same_machine(
    record: &MachineRecord,
    model: &FiveBar<f32>,
) -> Result<SameMachine, MachineMismatch> {
    let nominal = &record.nominal;
    if model.mode != nominal.mode {
        return Err(MachineMismatch::WorkingMode {
            image: model.mode,
            controller: nominal.mode,
        });
    }
    let tolerance_mm = record.limits.same_machine_tolerance_mm;
    let lattice = Lattice::of(record);
    let within = |s: &SameMachine| s.worst_mm <= tolerance_mm;
    let found = lattice.deviation(model);
    if let Ok(s) = &found {
        if within(s) {
            return Ok(*s);
        }
    }
    // The one parameter whose nominal value brings the model within the tolerance, the one
    // that brings it closest if several do.
    let mut explained: Option<(f32, ParameterDifference)> = None;
    for parameter in ModelParameter::ALL {
        let controller = parameter.of(nominal);
        let image = parameter.of(model);
        if image == controller {
            continue;
        }
        if let Ok(s) = lattice.deviation(&parameter.set(model, controller)) {
            let better = explained.is_none_or(|(w, _)| s.worst_mm < w);
            if within(&s) && better {
                let d = ParameterDifference {
                    parameter,
                    image,
                    controller,
                };
                explained = Some((s.worst_mm, d));
            }
        }
    }
    let parameter = explained.map(|(_, d)| d);
    Err(match found {
        Ok(s) => MachineMismatch::Geometry {
            worst_mm: s.worst_mm,
            at_mm: s.at_mm,
            tolerance_mm,
            parameter,
        },
        Err(at_mm) => MachineMismatch::Unreachable { at_mm, parameter },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rigid_fit_recovers_a_rotation_and_a_translation() {
        let from = [[0.0f64, 0.0], [10.0, 0.0], [10.0, 5.0], [3.0, 8.0]];
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let truth = RigidFrame {
            cos_sin: [c, s],
            translation_mm: [100.0, -20.0],
        };
        let to = from.map(|p| truth.apply(p));
        let fit = best_rigid_fit(&from, &to).unwrap();
        assert!((fit.rotation_rad() - 0.3).abs() < 1e-12);
        for (f, t) in from.iter().zip(&to) {
            let q = fit.apply(*f);
            assert!((q[0] - t[0]).abs() < 1e-9 && (q[1] - t[1]).abs() < 1e-9);
        }
        assert!(best_rigid_fit::<f64>(&[], &[]).is_none());
        assert!(best_rigid_fit(&[[f64::NAN, 0.0]], &[[0.0, 0.0]]).is_none());
    }

    #[test]
    fn the_nominal_is_its_own_machine_and_a_moved_tracker_changes_nothing() {
        let r = MachineRecord::paper();
        let s = same_machine(&r, &r.nominal).unwrap();
        assert!(s.worst_mm < 1e-3 && s.points == 81, "{s:?}");
        // The instrument 800 mm away and turned by 20°: A0 moves and turns, both offsets turn.
        let mut m = r.nominal;
        let (c, sn) = (20f32.to_radians().cos(), 20f32.to_radians().sin());
        m.base_a0_mm = [800.0, -300.0];
        m.base_b0_mm = [0.0, 0.0];
        m.encoder_offset_rad = [20f32.to_radians(); 2];
        let s = same_machine(&r, &m).unwrap();
        assert!(s.worst_mm < 2e-3, "{s:?}");
        assert!((s.frame.cos_sin[0] - c).abs() < 1e-5 && (s.frame.cos_sin[1] + sn).abs() < 1e-5);
    }
}
