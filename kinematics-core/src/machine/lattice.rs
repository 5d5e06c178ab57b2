//! The workspace points the judgements evaluate: a 9 × 9 lattice over the workspace's bounding
//! rectangle, edges included, keeping the points inside the polygon (a rectangle keeps all 81).
//! Fixed size, on the stack: no heap on the MCU.

use crate::workspace::ConvexWorkspace;

/// Lattice points per axis.
pub const LATTICE_PER_AXIS: usize = 9;
/// Most points a lattice holds.
pub const MAX_POINTS: usize = LATTICE_PER_AXIS * LATTICE_PER_AXIS;

/// The points of `region` on the lattice (module doc): the array and how many are used.
pub(crate) fn workspace_points(region: &ConvexWorkspace<f32>) -> ([[f32; 2]; MAX_POINTS], usize) {
    let (x, y) = region.bounds_mm();
    let mut out = [[0.0f32; 2]; MAX_POINTS];
    let mut n = 0;
    let last = (LATTICE_PER_AXIS - 1) as f32;
    for j in 0..LATTICE_PER_AXIS {
        for i in 0..LATTICE_PER_AXIS {
            let (u, v) = (i as f32 / last, j as f32 / last);
            let p = [x[0] + u * (x[1] - x[0]), y[0] + v * (y[1] - y[0])];
            if region.contains(p, 0.0) {
                out[n] = p;
                n += 1;
            }
        }
    }
    (out, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rectangle_keeps_every_point_and_a_triangle_about_half() {
        let r = ConvexWorkspace::rectangle([162.132f32, 262.132], [-75.0, 75.0]).unwrap();
        let (p, n) = workspace_points(&r);
        assert_eq!(n, MAX_POINTS);
        assert_eq!((p[0], p[80]), ([162.132, -75.0], [262.132, 75.0]));
        let t = ConvexWorkspace::new(&[[0.0f32, 0.0], [80.0, 0.0], [0.0, 80.0]]).unwrap();
        let (p, n) = workspace_points(&t);
        assert_eq!(n, 45, "the 9 + 8 + ... + 1 points on or below the diagonal");
        assert!(p[..n].iter().all(|q| q[0] + q[1] <= 80.0));
    }
}
