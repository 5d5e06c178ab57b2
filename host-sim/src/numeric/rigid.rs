//! Planar rigid transforms and the best-fitting one between two point sets (2-D Procrustes).
//!
//! Why: a laser tracker stands anywhere in the room; its readings are the machine's tool points
//! moved by a rotation and a shift. [`Rigid2`] is that motion, [`procrustes`] its least-squares
//! estimate from corresponding points (the calibration's registration of the instrument's frame,
//! `calib::frame`).
//!
//! Method: the closed form of the 2-D orthogonal Procrustes problem (Kabsch without the
//! reflection case): with the centroids removed, the rotation angle is
//! `atan2(Σ w·(p × q), Σ w·(p · q))` and the shift moves the rotated centroid onto the other.
//! Exact for noiseless data, a single pass, O(N). Reflections are not rigid motions and are
//! never returned (a mirrored set gives the best rotation, with a large residual).

/// `p ↦ R(rotation_rad)·p + offset_mm`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigid2 {
    pub rotation_rad: f64,
    pub offset_mm: [f64; 2],
}

impl Rigid2 {
    /// The identity.
    pub const IDENTITY: Rigid2 = Rigid2 {
        rotation_rad: 0.0,
        offset_mm: [0.0, 0.0],
    };

    /// `R·p` without the shift.
    pub fn rotate(&self, p: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.rotation_rad.sin_cos();
        [c * p[0] - s * p[1], s * p[0] + c * p[1]]
    }

    /// `R·p + t`.
    pub fn apply(&self, p: [f64; 2]) -> [f64; 2] {
        let r = self.rotate(p);
        [r[0] + self.offset_mm[0], r[1] + self.offset_mm[1]]
    }

    /// The inverse motion: `Rᵀ·(q − t)`.
    pub fn inverse(&self) -> Rigid2 {
        let back = Rigid2 {
            rotation_rad: -self.rotation_rad,
            offset_mm: [0.0, 0.0],
        };
        let t = back.rotate(self.offset_mm);
        Rigid2 {
            rotation_rad: -self.rotation_rad,
            offset_mm: [-t[0], -t[1]],
        }
    }

    /// `self ∘ inner`: first `inner`, then `self`.
    pub fn after(&self, inner: &Rigid2) -> Rigid2 {
        let t = self.apply(inner.offset_mm);
        Rigid2 {
            rotation_rad: self.rotation_rad + inner.rotation_rad,
            offset_mm: t,
        }
    }

    /// Whether every number is finite.
    pub fn is_finite(&self) -> bool {
        self.rotation_rad.is_finite() && self.offset_mm.iter().all(|v| v.is_finite())
    }
}

/// The rigid motion `T` minimising `Σ wᵢ·|T(fromᵢ) − toᵢ|²` (module doc). `None` when fewer
/// than two points carry weight, the weights are not finite and non-negative, or the `from`
/// points coincide (no direction to rotate).
pub fn procrustes(from: &[[f64; 2]], to: &[[f64; 2]], weights: Option<&[f64]>) -> Option<Rigid2> {
    if from.len() != to.len() || weights.is_some_and(|w| w.len() != from.len()) {
        return None;
    }
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let (mut sw, mut cp, mut cq, mut n) = (0.0, [0.0; 2], [0.0; 2], 0usize);
    for i in 0..from.len() {
        let wi = w(i);
        if !(wi >= 0.0 && wi.is_finite()) {
            return None;
        }
        if wi > 0.0 {
            n += 1;
        }
        sw += wi;
        for k in 0..2 {
            cp[k] += wi * from[i][k];
            cq[k] += wi * to[i][k];
        }
    }
    if n < 2 || !(sw > 0.0) {
        return None;
    }
    cp = cp.map(|v| v / sw);
    cq = cq.map(|v| v / sw);
    let (mut dot, mut cross, mut spread) = (0.0, 0.0, 0.0);
    for i in 0..from.len() {
        let wi = w(i);
        let p = [from[i][0] - cp[0], from[i][1] - cp[1]];
        let q = [to[i][0] - cq[0], to[i][1] - cq[1]];
        dot += wi * (p[0] * q[0] + p[1] * q[1]);
        cross += wi * (p[0] * q[1] - p[1] * q[0]);
        spread += wi * (p[0] * p[0] + p[1] * p[1]);
    }
    if !(spread > 0.0) || !(dot.hypot(cross) > 0.0) {
        return None;
    }
    let rotation_rad = cross.atan2(dot);
    let r = Rigid2 {
        rotation_rad,
        offset_mm: [0.0, 0.0],
    }
    .rotate(cp);
    let t = Rigid2 {
        rotation_rad,
        offset_mm: [cq[0] - r[0], cq[1] - r[1]],
    };
    t.is_finite().then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f64; 2], b: [f64; 2], tol: f64) -> bool {
        (a[0] - b[0]).abs() < tol && (a[1] - b[1]).abs() < tol
    }

    #[test]
    fn recovers_a_motion_of_metres_and_any_angle() {
        let pts: Vec<[f64; 2]> = (0..12)
            .map(|k| {
                let t = k as f64 * 0.7;
                [200.0 + 40.0 * t.cos(), 30.0 * t.sin()]
            })
            .collect();
        for &(rot, off) in &[
            (0.0, [0.0, 0.0]),
            (0.35f64.to_radians(), [12.5, -3.0]),
            (2.5, [-3250.0, 1800.0]),
            (-3.1, [5000.0, -7000.0]),
        ] {
            let t = Rigid2 {
                rotation_rad: rot,
                offset_mm: off,
            };
            let moved: Vec<[f64; 2]> = pts.iter().map(|&p| t.apply(p)).collect();
            let got = procrustes(&pts, &moved, None).unwrap();
            assert!((got.rotation_rad - rot).abs() < 1e-12, "{got:?}");
            assert!(close(got.offset_mm, off, 1e-9), "{got:?}");
            for (p, q) in pts.iter().zip(&moved) {
                assert!(close(t.inverse().apply(*q), *p, 1e-9));
                assert!(close(t.after(&t.inverse()).apply(*p), *p, 1e-9));
            }
        }
    }

    #[test]
    fn weights_and_degenerate_sets() {
        let a = [[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [500.0, 500.0]];
        let t = Rigid2 {
            rotation_rad: 0.2,
            offset_mm: [1.0, 2.0],
        };
        let mut b: Vec<[f64; 2]> = a.iter().map(|&p| t.apply(p)).collect();
        b[3] = [0.0, 0.0]; // an outlier, weighted out
        let got = procrustes(&a, &b, Some(&[1.0, 1.0, 1.0, 0.0])).unwrap();
        assert!((got.rotation_rad - 0.2).abs() < 1e-12);
        assert!(procrustes(&a[..1], &b[..1], None).is_none());
        assert!(procrustes(&[[1.0, 1.0]; 3], &[[2.0, 2.0]; 3], None).is_none());
        assert!(procrustes(&a, &b, Some(&[1.0, f64::NAN, 1.0, 1.0])).is_none());
    }
}
