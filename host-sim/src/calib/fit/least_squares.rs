//! The paper's least-squares synthesis of one dyad (Sec. III-B, Eqs. 4–6).
//!
//! Why: with more than two design points the dyad equation `P1 + P2·f2 = F` (see [`super::poly`])
//! is overdetermined; the paper minimises `S = Σ δi²` of its *algebraic* residual
//! `δi = P1 + P2·f2i − Fi` (mm², not a distance), which Eq. 6 turns into 2x2 normal equations.
//! Note what this does and does not minimise: δi ≈ 2·distal·(distance error along the distal
//! link), so it weights points roughly evenly but ignores the error across the link and the
//! coupling of the two dyads through C: it is not the position error (that is `full`).
//!
//! Cost: O(n) sums and a 2x2 solve. Error: exact for n = 2 (same as `poly`).

use super::poly::{links_from_p, DyadPoint};
use crate::calib::{invalid, CalibError};

/// The sums of the normal equations (Eq. 6) of a set of dyad points. Why a type: leave-one-out
/// of the all-points fit is the sums less one point's terms, O(1) per point instead of a refit
/// over N − 1 points (O(N²) in all; 100,000 rows took minutes).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DyadSums {
    n: f64,
    s_f2: f64,
    s_f2f2: f64,
    s_big_f: f64,
    s_big_f_f2: f64,
}

impl DyadSums {
    /// The sums over `points`.
    pub fn of(points: &[DyadPoint]) -> Self {
        points
            .iter()
            .fold(DyadSums::default(), |acc, p| acc.with(p, 1.0))
    }

    /// The sums with `p` added (`sign` = 1) or removed (−1).
    fn with(self, p: &DyadPoint, sign: f64) -> Self {
        let (f2, big_f) = (p.f2_mm(), p.big_f_mm2());
        DyadSums {
            n: self.n + sign,
            s_f2: self.s_f2 + sign * f2,
            s_f2f2: self.s_f2f2 + sign * f2 * f2,
            s_big_f: self.s_big_f + sign * big_f,
            s_big_f_f2: self.s_big_f_f2 + sign * big_f * f2,
        }
    }

    /// The sums without `p` (which must be one of the points summed).
    pub fn without(self, p: &DyadPoint) -> Self {
        self.with(p, -1.0)
    }

    /// `(proximal_mm, distal_mm)` solving the normal equations
    /// `[n Σf2; Σf2 Σf2²] [P1; P2] = [ΣF; ΣF·f2]`.
    pub fn solve(&self) -> Result<(f64, f64), CalibError> {
        if self.n < 1.5 {
            return Err(invalid!(
                "least squares needs at least 2 points per dyad, got {}",
                self.n.round()
            ));
        }
        let det = self.n * self.s_f2f2 - self.s_f2 * self.s_f2;
        if !(det.abs() > 1e-12 * self.n * self.s_f2f2) {
            return Err(invalid!(
                "the design points are degenerate for this dyad (all f2 equal)"
            ));
        }
        let p1 = (self.s_big_f * self.s_f2f2 - self.s_f2 * self.s_big_f_f2) / det;
        let p2 = (self.n * self.s_big_f_f2 - self.s_f2 * self.s_big_f) / det;
        links_from_p(p1, p2)
    }
}

/// `(proximal_mm, distal_mm)` minimising Σ (P1 + P2·f2 − F)² over `points` (n ≥ 2).
pub fn least_squares_dyad(points: &[DyadPoint]) -> Result<(f64, f64), CalibError> {
    if points.len() < 2 {
        return Err(invalid!(
            "least squares needs at least 2 points per dyad, got {}",
            points.len()
        ));
    }
    DyadSums::of(points).solve()
}

#[cfg(test)]
mod tests {
    use super::super::poly::precision_point_dyad;
    use super::*;

    #[test]
    fn two_points_equal_the_precision_point_solution() {
        let pts = [
            DyadPoint {
                theta_rad: 0.7,
                x_mm: 212.0,
                y_mm: 1.0,
            },
            DyadPoint {
                theta_rad: 1.0,
                x_mm: 162.0,
                y_mm: -0.5,
            },
        ];
        let (a, b) = least_squares_dyad(&pts).unwrap();
        let (pa, pb) = precision_point_dyad(pts).unwrap();
        assert!((a - pa).abs() < 1e-9 && (b - pb).abs() < 1e-9);
    }

    #[test]
    fn sums_without_a_point_equal_the_fit_on_the_rest() {
        let pts: Vec<DyadPoint> = (0..7)
            .map(|k| {
                // A dyad of 150 / 151 mm, its distal link at any angle, with a little noise.
                let (t, phi) = (0.4 + 0.1 * k as f64, -0.9 + 0.23 * k as f64);
                let noise = 0.01 * ((k * k) % 5) as f64;
                DyadPoint {
                    theta_rad: t,
                    x_mm: 150.0 * t.cos() + 151.0 * phi.cos() + noise,
                    y_mm: 150.0 * t.sin() + 151.0 * phi.sin(),
                }
            })
            .collect();
        let all = DyadSums::of(&pts);
        for i in 0..pts.len() {
            let rest: Vec<DyadPoint> = pts
                .iter()
                .enumerate()
                .filter(|(k, _)| *k != i)
                .map(|(_, p)| *p)
                .collect();
            let (a, b) = least_squares_dyad(&rest).unwrap();
            let (da, db) = all.without(&pts[i]).solve().unwrap();
            assert!(
                (a - da).abs() < 1e-7 && (b - db).abs() < 1e-7,
                "point {i}: {a} {b} vs {da} {db}"
            );
        }
    }
}
