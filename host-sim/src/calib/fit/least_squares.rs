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

/// `(proximal_mm, distal_mm)` minimising Σ (P1 + P2·f2 − F)² over `points` (n ≥ 2).
pub fn least_squares_dyad(points: &[DyadPoint]) -> Result<(f64, f64), CalibError> {
    if points.len() < 2 {
        return Err(invalid!("least squares needs at least 2 points per dyad, got {}", points.len()));
    }
    // Normal equations (Eq. 6): [n Σf2; Σf2 Σf2²] [P1; P2] = [ΣF; ΣF·f2].
    let n = points.len() as f64;
    let (mut s_f2, mut s_f2f2, mut s_big_f, mut s_big_f_f2) = (0.0, 0.0, 0.0, 0.0);
    for p in points {
        let (f2, big_f) = (p.f2_mm(), p.big_f_mm2());
        s_f2 += f2;
        s_f2f2 += f2 * f2;
        s_big_f += big_f;
        s_big_f_f2 += big_f * f2;
    }
    let det = n * s_f2f2 - s_f2 * s_f2;
    if !(det.abs() > 1e-12 * n * s_f2f2) {
        return Err(invalid!("the design points are degenerate for this dyad (all f2 equal)"));
    }
    let p1 = (s_big_f * s_f2f2 - s_f2 * s_big_f_f2) / det;
    let p2 = (n * s_big_f_f2 - s_f2 * s_big_f) / det;
    links_from_p(p1, p2)
}

#[cfg(test)]
mod tests {
    use super::super::poly::precision_point_dyad;
    use super::*;

    #[test]
    fn two_points_equal_the_precision_point_solution() {
        let pts = [
            DyadPoint { theta_rad: 0.7, x_mm: 212.0, y_mm: 1.0 },
            DyadPoint { theta_rad: 1.0, x_mm: 162.0, y_mm: -0.5 },
        ];
        let (a, b) = least_squares_dyad(&pts).unwrap();
        let (pa, pb) = precision_point_dyad(pts).unwrap();
        assert!((a - pa).abs() < 1e-9 && (b - pb).abs() < 1e-9);
    }
}
