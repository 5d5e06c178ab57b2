//! Bilinear interpolation inside one grid cell: the paper's Eq. 7.
//!
//! Eq. 7 weighs the four corner values by the areas of the opposite sub-rectangles,
//! `δ = [(x2-x)(y2-y)δ11 + (x2-x)(y-y1)δ12 + (x-x1)(y2-y)δ21 + (x-x1)(y-y1)δ22] / ((x2-x1)(y2-y1))`.
//! With the cell-relative coordinates `u = (x-x1)/(x2-x1)`, `v = (y-y1)/(y2-y1)` in `[0, 1]`
//! that is exactly the expression below; on an edge (`u` or `v` 0 or 1) it reduces to the
//! linear interpolation between the two nodes of that edge, as the paper states, and on a node
//! to the node's value. Cost: 8 multiplications and 7 additions per interpolated quantity.

use crate::real::Real;

/// Interpolates between `d11 = δ(x1,y1)`, `d12 = δ(x1,y2)`, `d21 = δ(x2,y1)`, `d22 = δ(x2,y2)`
/// at the cell-relative position `(u, v)`.
#[inline]
pub fn bilinear<T: Real>(d11: T, d12: T, d21: T, d22: T, u: T, v: T) -> T {
    let (nu, nv) = (T::ONE - u, T::ONE - v);
    nu * nv * d11 + nu * v * d12 + u * nv * d21 + u * v * d22
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eq. 7 written as printed, for comparison.
    fn eq7(x: f64, y: f64, x1: f64, x2: f64, y1: f64, y2: f64, d: [f64; 4]) -> f64 {
        ((x2 - x) * (y2 - y) * d[0]
            + (x2 - x) * (y - y1) * d[1]
            + (x - x1) * (y2 - y) * d[2]
            + (x - x1) * (y - y1) * d[3])
            / ((x2 - x1) * (y2 - y1))
    }

    #[test]
    fn matches_eq7_inside_on_edges_and_nodes() {
        let d = [1.5, -2.0, 0.25, 4.0];
        let (x1, x2, y1, y2) = (10.0, 15.0, -5.0, 0.0);
        for i in 0..=10 {
            for j in 0..=10 {
                let (x, y) = (x1 + 0.5 * i as f64, y1 + 0.5 * j as f64);
                let (u, v) = ((x - x1) / (x2 - x1), (y - y1) / (y2 - y1));
                let got = bilinear(d[0], d[1], d[2], d[3], u, v);
                assert!((got - eq7(x, y, x1, x2, y1, y2, d)).abs() < 1e-12);
            }
        }
        // Edge x = x1: linear between Q11 and Q12.
        assert!(
            (bilinear(d[0], d[1], d[2], d[3], 0.0, 0.25) - (0.75 * d[0] + 0.25 * d[1])).abs()
                < 1e-15
        );
        assert_eq!(bilinear(d[0], d[1], d[2], d[3], 1.0, 1.0), d[3]);
    }
}
