//! The machine's workspace: a convex polygon in the machine frame (mm), shared by the host tools
//! (which targets a calibration is valid for) and the firmware (where a controlled stop may
//! end).
//!
//! # Why convex
//! The firmware's controlled stop runs on a straight line and checks only its **end point**
//! (`firmware/controller/src/stop.rs`): a segment between two points of a convex region lies
//! inside it, so a stop that starts and ends inside never leaves it. A concave workspace would
//! need every point of the stop checked. [`ConvexWorkspace::new`] therefore refuses any polygon
//! that is not strictly convex and counter-clockwise (which also refuses self-intersecting and
//! degenerate ones).
//!
//! # The check
//! Each edge `i` (from vertex `i` to `i + 1`) stores its inward unit normal `n_i` and offset
//! `c_i = n_i · v_i`; a point `p` is inside with margin `m` when `n_i · p − c_i ≥ m` for every
//! edge, i.e. at least `m` from every edge's line. Cost: per edge two multiplications, two
//! additions and a comparison (a rectangle: 4 edges, about 20 instructions on the Cortex-M4F);
//! the normals are computed once in [`ConvexWorkspace::new`]. Error: for axis-aligned edges the
//! normal is exactly `(0, ±1)` or `(±1, 0)` (a rectangle's check is exact); others carry the
//! rounding of one normalisation, < 1e-6 of the coordinates in f32 (0.3 µm at 300 mm).

use crate::real::Real;

/// Most vertices a workspace polygon may have (the flash image's fixed block holds this many).
pub const MAX_WORKSPACE_VERTICES: usize = 16;

/// Why a polygon is not a workspace.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WorkspaceError {
    /// Fewer than 3 or more than [`MAX_WORKSPACE_VERTICES`] vertices.
    VertexCount,
    /// A coordinate is NaN or infinite.
    NonFinite,
    /// Not strictly convex and counter-clockwise: a vertex is not strictly to the left of
    /// some edge (clockwise, concave, self-intersecting, repeated or collinear vertices).
    NotConvex,
}

impl core::fmt::Display for WorkspaceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WorkspaceError::VertexCount => write!(
                f,
                "a workspace polygon has 3..={MAX_WORKSPACE_VERTICES} vertices"
            ),
            WorkspaceError::NonFinite => f.write_str("a workspace vertex is not finite"),
            WorkspaceError::NotConvex => f.write_str(
                "the workspace polygon is not strictly convex with its vertices counter-clockwise",
            ),
        }
    }
}

impl core::error::Error for WorkspaceError {}

/// A validated convex workspace (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConvexWorkspace<T> {
    vertices_mm: [[T; 2]; MAX_WORKSPACE_VERTICES],
    /// Inward unit normal of edge `i` (vertex `i` to vertex `i + 1`).
    normals: [[T; 2]; MAX_WORKSPACE_VERTICES],
    /// `normals[i] · vertices[i]`.
    offsets_mm: [T; MAX_WORKSPACE_VERTICES],
    len: usize,
}

impl<T: Real> ConvexWorkspace<T> {
    /// A workspace from its vertices, counter-clockwise (x right, y up).
    pub fn new(vertices_mm: &[[T; 2]]) -> Result<Self, WorkspaceError> {
        let n = vertices_mm.len();
        if !(3..=MAX_WORKSPACE_VERTICES).contains(&n) {
            return Err(WorkspaceError::VertexCount);
        }
        if vertices_mm.iter().flatten().any(|v| !v.is_finite()) {
            return Err(WorkspaceError::NonFinite);
        }
        let mut w = ConvexWorkspace {
            vertices_mm: [[T::ZERO; 2]; MAX_WORKSPACE_VERTICES],
            normals: [[T::ZERO; 2]; MAX_WORKSPACE_VERTICES],
            offsets_mm: [T::ZERO; MAX_WORKSPACE_VERTICES],
            len: n,
        };
        w.vertices_mm[..n].copy_from_slice(vertices_mm);
        for i in 0..n {
            let (p, q) = (vertices_mm[i], vertices_mm[(i + 1) % n]);
            let e = [q[0] - p[0], q[1] - p[1]];
            // Every other vertex strictly to the left of this edge: convex, counter-clockwise,
            // simple, no repeated or collinear vertices (O(n²), n ≤ 16, once).
            for (k, v) in vertices_mm.iter().enumerate() {
                if k != i
                    && k != (i + 1) % n
                    && !(e[0] * (v[1] - p[1]) - e[1] * (v[0] - p[0]) > T::ZERO)
                {
                    return Err(WorkspaceError::NotConvex);
                }
            }
            let len = (e[0] * e[0] + e[1] * e[1]).sqrt();
            if !(len > T::ZERO) || !len.is_finite() {
                return Err(WorkspaceError::NotConvex);
            }
            let normal = [-e[1] / len, e[0] / len];
            w.normals[i] = normal;
            w.offsets_mm[i] = normal[0] * p[0] + normal[1] * p[1];
        }
        Ok(w)
    }

    /// The rectangle `[x0, x1] × [y0, y1]` (vertices from the lower left, counter-clockwise).
    pub fn rectangle(x_mm: [T; 2], y_mm: [T; 2]) -> Result<Self, WorkspaceError> {
        Self::new(&[
            [x_mm[0], y_mm[0]],
            [x_mm[1], y_mm[0]],
            [x_mm[1], y_mm[1]],
            [x_mm[0], y_mm[1]],
        ])
    }

    /// The rectangle `[x0, x1] × [y0, y1]` built without checks, for constants known to be
    /// one (`x0 < x1`, `y0 < y1`, finite): the same value [`Self::rectangle`] returns for
    /// them (a test checks), and no error path where there can be no error.
    pub(crate) fn rectangle_unchecked(x_mm: [T; 2], y_mm: [T; 2]) -> Self {
        let o = T::ONE;
        let z = T::ZERO;
        let mut w = ConvexWorkspace {
            vertices_mm: [[z; 2]; MAX_WORKSPACE_VERTICES],
            normals: [[z; 2]; MAX_WORKSPACE_VERTICES],
            offsets_mm: [z; MAX_WORKSPACE_VERTICES],
            len: 4,
        };
        w.vertices_mm[..4].copy_from_slice(&[
            [x_mm[0], y_mm[0]],
            [x_mm[1], y_mm[0]],
            [x_mm[1], y_mm[1]],
            [x_mm[0], y_mm[1]],
        ]);
        w.normals[..4].copy_from_slice(&[[-z, o], [-o, z], [z, -o], [o, z]]);
        w.offsets_mm[..4].copy_from_slice(&[y_mm[0], -x_mm[1], -y_mm[1], x_mm[0]]);
        w
    }

    /// The vertices, counter-clockwise.
    pub fn vertices_mm(&self) -> &[[T; 2]] {
        &self.vertices_mm[..self.len]
    }

    /// Whether `p_mm` is inside and at least `margin_mm` from every edge (on the edge counts
    /// with a zero margin; NaN never does).
    #[inline]
    pub fn contains(&self, p_mm: [T; 2], margin_mm: T) -> bool {
        let mut inside = true;
        for i in 0..self.len {
            let n = self.normals[i];
            let d = n[0] * p_mm[0] + n[1] * p_mm[1] - self.offsets_mm[i];
            inside &= d >= margin_mm;
        }
        inside
    }

    /// Smallest distance from `p_mm` to an edge's line (mm): positive inside, negative outside.
    pub fn clearance_mm(&self, p_mm: [T; 2]) -> T {
        let mut worst = T::from_f64(f64::INFINITY);
        for i in 0..self.len {
            let n = self.normals[i];
            worst = worst.min(n[0] * p_mm[0] + n[1] * p_mm[1] - self.offsets_mm[i]);
        }
        worst
    }

    /// The bounding rectangle: `([x_min, x_max], [y_min, y_max])`.
    pub fn bounds_mm(&self) -> ([T; 2], [T; 2]) {
        let v = self.vertices_mm();
        let mut x = [v[0][0]; 2];
        let mut y = [v[0][1]; 2];
        for p in v {
            x = [x[0].min(p[0]), x[1].max(p[0])];
            y = [y[0].min(p[1]), y[1].max(p[1])];
        }
        (x, y)
    }

    /// The same workspace in another scalar type (vertices rounded to nearest, then checked
    /// again: a polygon that rounding makes non-convex is refused).
    pub fn cast<U: Real>(&self) -> Result<ConvexWorkspace<U>, WorkspaceError> {
        let mut v = [[U::ZERO; 2]; MAX_WORKSPACE_VERTICES];
        for (out, p) in v.iter_mut().zip(self.vertices_mm()) {
            *out = [U::from_f64(p[0].to_f64()), U::from_f64(p[1].to_f64())];
        }
        ConvexWorkspace::new(&v[..self.len])
    }
}

/// Where the machine may be commanded and where a controlled stop must end: the polygon and the
/// soft limit (what the calibration image's workspace block and the machine record hold).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WorkspaceLimits {
    /// Where the machine may be commanded (mm, machine frame).
    pub region: ConvexWorkspace<f32>,
    /// How far inside `region` a controlled stop must end (mm, ≥ 0).
    pub stop_margin_mm: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper() -> ConvexWorkspace<f32> {
        ConvexWorkspace::rectangle([162.132, 262.132], [-75.0, 75.0]).unwrap()
    }

    #[test]
    fn a_rectangle_checks_exactly_with_and_without_margin() {
        let w = paper();
        assert_eq!(w.vertices_mm().len(), 4);
        for p in [
            [162.132, -75.0],
            [262.132, 75.0],
            [212.132, 0.0],
            [162.132, 10.0],
        ] {
            assert!(w.contains(p, 0.0), "{p:?}");
        }
        for p in [
            [162.13, 0.0],
            [212.0, 75.001],
            [f32::NAN, 0.0],
            [300.0, 0.0],
        ] {
            assert!(!w.contains(p, 0.0), "{p:?}");
        }
        assert!(w.contains([162.24, -74.89], 0.1) && !w.contains([162.2, 0.0], 0.1));
        assert_eq!(w.bounds_mm(), ([162.132, 262.132], [-75.0, 75.0]));
        assert!((w.clearance_mm([212.132, 70.0]) - 5.0).abs() < 1e-4);
        assert!(w.clearance_mm([100.0, 0.0]) < -60.0);
    }

    #[test]
    fn the_unchecked_rectangle_is_the_checked_one() {
        let (x, y) = ([162.132f32, 262.132], [-75.0f32, 75.0]);
        let a = ConvexWorkspace::rectangle(x, y).unwrap();
        let b = ConvexWorkspace::rectangle_unchecked(x, y);
        assert_eq!(a, b);
        for p in [[162.132, 0.0], [262.2, 0.0], [200.0, 75.1], [200.0, -75.0]] {
            assert_eq!(a.clearance_mm(p), b.clearance_mm(p));
        }
    }

    #[test]
    fn a_convex_polygon_and_its_margin() {
        // A hexagon: the paper rectangle with two corners cut at 45°.
        let v = [
            [172.0f64, -75.0],
            [262.0, -75.0],
            [262.0, 65.0],
            [252.0, 75.0],
            [162.0, 75.0],
            [162.0, -65.0],
        ];
        let w = ConvexWorkspace::new(&v).unwrap();
        assert!(w.contains([170.0, -70.0], 0.0) && !w.contains([163.0, -74.0], 0.0));
        // (258, 70) is 1/√2·(262+75−65... ) from the cut: x + y ≤ 327 → distance (327−328)/√2 < 0.
        assert!(!w.contains([258.0, 70.0], 0.0) && w.contains([256.0, 70.0], 0.0));
        let d = w.clearance_mm([256.0, 70.0]);
        assert!((d - 1.0 / 2f64.sqrt()).abs() < 1e-12, "{d}");
        assert!(w.contains([256.0, 70.0], 0.7) && !w.contains([256.0, 70.0], 0.71));
        // Cast to f32 keeps it.
        let w32 = w.cast::<f32>().unwrap();
        assert!(w32.contains([256.0, 70.0], 0.7) && !w32.contains([258.0, 70.0], 0.0));
    }

    #[test]
    fn bad_polygons_are_refused() {
        let sq = [[0.0f64, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        assert!(ConvexWorkspace::new(&sq).is_ok());
        let mut cw = sq;
        cw.reverse();
        assert_eq!(
            ConvexWorkspace::new(&cw),
            Err(WorkspaceError::NotConvex),
            "clockwise"
        );
        let concave = [[0.0, 0.0], [2.0, 0.0], [1.0, 0.5], [2.0, 2.0], [0.0, 2.0]];
        assert_eq!(
            ConvexWorkspace::new(&concave),
            Err(WorkspaceError::NotConvex)
        );
        let collinear = [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0]];
        assert_eq!(
            ConvexWorkspace::new(&collinear),
            Err(WorkspaceError::NotConvex)
        );
        let repeated = [[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
        assert_eq!(
            ConvexWorkspace::new(&repeated),
            Err(WorkspaceError::NotConvex)
        );
        // A pentagram: every turn has the same sign, but it winds twice.
        let star: [[f64; 2]; 5] = core::array::from_fn(|k| {
            let a = core::f64::consts::TAU * (2 * k) as f64 / 5.0;
            [libm::cos(a), libm::sin(a)]
        });
        assert_eq!(ConvexWorkspace::new(&star), Err(WorkspaceError::NotConvex));
        assert_eq!(
            ConvexWorkspace::new(&sq[..2]),
            Err(WorkspaceError::VertexCount)
        );
        assert_eq!(
            ConvexWorkspace::new(&[[0.0, 0.0]; 17]),
            Err(WorkspaceError::VertexCount)
        );
        assert_eq!(
            ConvexWorkspace::new(&[[0.0, 0.0], [1.0, f64::NAN], [0.0, 1.0]]),
            Err(WorkspaceError::NonFinite)
        );
        assert_eq!(
            ConvexWorkspace::<f64>::rectangle([1.0, 0.0], [0.0, 1.0]),
            Err(WorkspaceError::NotConvex)
        );
    }
}
