//! The paper's polynomial (precision-point) synthesis of one dyad (Sec. III-A, Eqs. 1–3).
//!
//! Why: it is the paper's first hidden-robot fit, and with two well-chosen points it is what the
//! paper shipped. For the dyad A0–A–C with motor angle θ (geometric, i.e. encoder + offset) and
//! tool point C = (x, y) relative to the dyad's base, |C − A|² = distal² expands to the linear
//! equation `P1 + P2·f2 = F` with `P1 = distal² − proximal²`, `P2 = proximal`,
//! `f2 = 2(x cos θ + y sin θ)`, `F = x² + y²`. Two precision points give P1, P2 exactly; then
//! `proximal = P2`, `distal = sqrt(P1 + P2²)` (the paper's Eq. 3 prints `sqrt(a² + P1²)`: a typo,
//! P1 is already a difference of squares).
//!
//! Cost: a 2x2 solve. Error: exact at the two points; the model's error elsewhere is whatever
//! the data disagree with a rigid five-bar (see `docs/design/hidden-robot.md`).

use crate::calib::{invalid, CalibError};

/// One observation of a dyad: geometric motor angle and tool point relative to the dyad's base.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DyadPoint {
    pub theta_rad: f64,
    pub x_mm: f64,
    pub y_mm: f64,
}

impl DyadPoint {
    /// `f2 = 2(x cos θ + y sin θ)` of Eq. 2.
    pub fn f2_mm(&self) -> f64 {
        2.0 * (self.x_mm * self.theta_rad.cos() + self.y_mm * self.theta_rad.sin())
    }

    /// `F = x² + y²` of Eq. 2.
    pub fn big_f_mm2(&self) -> f64 {
        self.x_mm * self.x_mm + self.y_mm * self.y_mm
    }
}

/// Link lengths `(proximal, distal)` from `P1`, `P2` (Eq. 3, corrected).
pub fn links_from_p(p1_mm2: f64, p2_mm: f64) -> Result<(f64, f64), CalibError> {
    let distal2 = p1_mm2 + p2_mm * p2_mm;
    if !(p2_mm > 0.0) || !(distal2 > 0.0) || !distal2.is_finite() {
        return Err(invalid!(
            "the points give no real dyad (proximal {p2_mm:.6} mm, distal² {distal2:.6} mm²)"
        ));
    }
    Ok((p2_mm, distal2.sqrt()))
}

/// Exact synthesis through two precision points: `(proximal_mm, distal_mm)`.
pub fn precision_point_dyad(points: [DyadPoint; 2]) -> Result<(f64, f64), CalibError> {
    let [p, q] = points;
    let df2 = p.f2_mm() - q.f2_mm();
    // Two points the dyad sees alike (same f2) leave P1, P2 undetermined.
    if !(df2.abs() > 1e-9 * (p.f2_mm().abs() + q.f2_mm().abs())) {
        return Err(invalid!(
            "the two precision points are degenerate for this dyad (equal f2 = {:.6} mm)",
            p.f2_mm()
        ));
    }
    let p2 = (p.big_f_mm2() - q.big_f_mm2()) / df2;
    let p1 = p.big_f_mm2() - p2 * p.f2_mm();
    links_from_p(p1, p2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_dyad_exactly() {
        let (a, b) = (149.87, 150.02);
        let pt = |th: f64, phi: f64| {
            let (ax, ay) = (a * th.cos(), a * th.sin());
            DyadPoint {
                theta_rad: th,
                x_mm: ax + b * phi.cos(),
                y_mm: ay + b * phi.sin(),
            }
        };
        let (pa, pb) = precision_point_dyad([pt(0.7, -0.6), pt(1.1, 0.1)]).unwrap();
        assert!((pa - a).abs() < 1e-9 && (pb - b).abs() < 1e-9, "{pa} {pb}");
        assert!(precision_point_dyad([pt(0.7, -0.6), pt(0.7, -0.6)]).is_err());
    }
}
