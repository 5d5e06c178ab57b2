//! The programmed path's geometry: straight lines and circular arcs, each parameterised by arc
//! length, with the tangent and curvature a time law needs, and the distance from a point to
//! it (the contour error).
//!
//! Conventions: an arc's `sweep_rad` is signed (counter-clockwise positive); its signed
//! curvature is `+1/R` turning left (`G3`) and `−1/R` turning right (`G2`); a line's is 0. The
//! motion along a segment at path speed `ṡ`, acceleration `s̈`, jerk `s⃛` is
//! `v = ṡ·T`, `a = s̈·T + κ·ṡ²·N`, `j = (s⃛ − κ²·ṡ³)·T + 3·κ·ṡ·s̈·N` with `N` the left normal.

use std::f64::consts::{FRAC_PI_2, TAU};

/// One segment of the programmed path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Segment {
    Line {
        from_mm: [f64; 2],
        to_mm: [f64; 2],
        /// Unit direction (zero for a zero-length line).
        dir: [f64; 2],
        length_mm: f64,
    },
    Arc {
        from_mm: [f64; 2],
        to_mm: [f64; 2],
        centre_mm: [f64; 2],
        radius_mm: f64,
        start_rad: f64,
        /// Signed: counter-clockwise positive; a full circle is ±2π.
        sweep_rad: f64,
    },
}

/// A point of a segment: position, unit tangent and signed curvature.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathPoint {
    pub position_mm: [f64; 2],
    pub tangent: [f64; 2],
    pub curvature_per_mm: f64,
}

impl PathPoint {
    /// The motion at path speed `v`, acceleration `a`, jerk `j`: (velocity, acceleration,
    /// jerk) of the tool (see the module doc).
    pub fn motion(&self, v: f64, a: f64, j: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
        let (t, k) = (self.tangent, self.curvature_per_mm);
        let n = [-t[1], t[0]];
        let at = (a, k * v * v);
        let jt = (j - k * k * v * v * v, 3.0 * k * v * a);
        (
            [v * t[0], v * t[1]],
            [at.0 * t[0] + at.1 * n[0], at.0 * t[1] + at.1 * n[1]],
            [jt.0 * t[0] + jt.1 * n[0], jt.0 * t[1] + jt.1 * n[1]],
        )
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

impl Segment {
    /// The straight segment from `from_mm` to `to_mm`.
    pub fn line(from_mm: [f64; 2], to_mm: [f64; 2]) -> Self {
        let length_mm = dist(from_mm, to_mm);
        let dir = if length_mm > 0.0 {
            [
                (to_mm[0] - from_mm[0]) / length_mm,
                (to_mm[1] - from_mm[1]) / length_mm,
            ]
        } else {
            [0.0; 2]
        };
        Segment::Line {
            from_mm,
            to_mm,
            dir,
            length_mm,
        }
    }

    /// The arc about `centre_mm` from `from_mm` to `to_mm` (a full circle when they coincide),
    /// counter-clockwise if `ccw`; `None` for a zero radius or non-finite input.
    pub fn arc(from_mm: [f64; 2], to_mm: [f64; 2], centre_mm: [f64; 2], ccw: bool) -> Option<Self> {
        let radius_mm = dist(from_mm, centre_mm);
        if !(radius_mm > 1e-9 && radius_mm.is_finite() && to_mm.iter().all(|v| v.is_finite())) {
            return None;
        }
        let start_rad = (from_mm[1] - centre_mm[1]).atan2(from_mm[0] - centre_mm[0]);
        let end_rad = (to_mm[1] - centre_mm[1]).atan2(to_mm[0] - centre_mm[0]);
        let mut sweep = (end_rad - start_rad).rem_euclid(TAU);
        if !ccw {
            sweep -= TAU;
            if sweep <= -TAU {
                sweep += TAU;
            }
        }
        // The end on the start (to within a nanometre of arc): a full circle.
        if (sweep.abs() * radius_mm) < 1e-6 || (TAU - sweep.abs()) * radius_mm < 1e-6 {
            sweep = if ccw { TAU } else { -TAU };
            if dist(from_mm, to_mm) > 1e-6 {
                sweep = 0.0;
            }
        }
        if sweep == 0.0 {
            return None;
        }
        Some(Segment::Arc {
            from_mm,
            to_mm,
            centre_mm,
            radius_mm,
            start_rad,
            sweep_rad: sweep,
        })
    }

    /// Length along the path (mm).
    pub fn length_mm(&self) -> f64 {
        match *self {
            Segment::Line { length_mm, .. } => length_mm,
            Segment::Arc {
                radius_mm,
                sweep_rad,
                ..
            } => radius_mm * sweep_rad.abs(),
        }
    }

    pub fn start_mm(&self) -> [f64; 2] {
        match *self {
            Segment::Line { from_mm, .. } | Segment::Arc { from_mm, .. } => from_mm,
        }
    }

    pub fn end_mm(&self) -> [f64; 2] {
        match *self {
            Segment::Line { to_mm, .. } | Segment::Arc { to_mm, .. } => to_mm,
        }
    }

    /// Signed curvature (1/mm): 0 on a line, ±1/R on an arc.
    pub fn curvature_per_mm(&self) -> f64 {
        match *self {
            Segment::Line { .. } => 0.0,
            Segment::Arc {
                radius_mm,
                sweep_rad,
                ..
            } => sweep_rad.signum() / radius_mm,
        }
    }

    /// The point `s_mm` along the segment (clamped to it).
    pub fn at(&self, s_mm: f64) -> PathPoint {
        let s = s_mm.clamp(0.0, self.length_mm());
        match *self {
            Segment::Line {
                from_mm,
                to_mm,
                dir,
                length_mm,
            } => PathPoint {
                position_mm: if s >= length_mm {
                    to_mm
                } else {
                    [from_mm[0] + s * dir[0], from_mm[1] + s * dir[1]]
                },
                tangent: dir,
                curvature_per_mm: 0.0,
            },
            Segment::Arc {
                centre_mm,
                radius_mm,
                start_rad,
                sweep_rad,
                to_mm,
                ..
            } => {
                let sign = sweep_rad.signum();
                let th = start_rad + sign * s / radius_mm;
                let (sn, cs) = th.sin_cos();
                PathPoint {
                    position_mm: if s >= self.length_mm() {
                        to_mm
                    } else {
                        [centre_mm[0] + radius_mm * cs, centre_mm[1] + radius_mm * sn]
                    },
                    tangent: [-sign * sn, sign * cs],
                    curvature_per_mm: sign / radius_mm,
                }
            }
        }
    }

    /// The unit tangent at the start and at the end.
    pub fn tangents(&self) -> ([f64; 2], [f64; 2]) {
        (self.at(0.0).tangent, self.at(self.length_mm()).tangent)
    }

    /// The bounding box `(low, high)` (mm), an arc's bulges included.
    pub fn bounds_mm(&self) -> ([f64; 2], [f64; 2]) {
        let (a, b) = (self.start_mm(), self.end_mm());
        let mut lo = [a[0].min(b[0]), a[1].min(b[1])];
        let mut hi = [a[0].max(b[0]), a[1].max(b[1])];
        if let Segment::Arc {
            centre_mm,
            radius_mm,
            start_rad,
            sweep_rad,
            ..
        } = *self
        {
            for k in 0..4 {
                let ang = k as f64 * FRAC_PI_2;
                // How far along the sweep the axis point lies.
                let rel = if sweep_rad > 0.0 {
                    (ang - start_rad).rem_euclid(TAU)
                } else {
                    (start_rad - ang).rem_euclid(TAU)
                };
                if rel <= sweep_rad.abs() {
                    let p = [
                        centre_mm[0] + radius_mm * ang.cos(),
                        centre_mm[1] + radius_mm * ang.sin(),
                    ];
                    for i in 0..2 {
                        lo[i] = lo[i].min(p[i]);
                        hi[i] = hi[i].max(p[i]);
                    }
                }
            }
        }
        (lo, hi)
    }

    /// Distance from `q_mm` to the segment (mm).
    pub fn distance_mm(&self, q_mm: [f64; 2]) -> f64 {
        match *self {
            Segment::Line {
                from_mm,
                dir,
                length_mm,
                ..
            } => {
                let d = [q_mm[0] - from_mm[0], q_mm[1] - from_mm[1]];
                let s = (d[0] * dir[0] + d[1] * dir[1]).clamp(0.0, length_mm);
                dist(q_mm, [from_mm[0] + s * dir[0], from_mm[1] + s * dir[1]])
            }
            Segment::Arc {
                centre_mm,
                radius_mm,
                start_rad,
                sweep_rad,
                from_mm,
                to_mm,
            } => {
                let ang = (q_mm[1] - centre_mm[1]).atan2(q_mm[0] - centre_mm[0]);
                let rel = if sweep_rad > 0.0 {
                    (ang - start_rad).rem_euclid(TAU)
                } else {
                    (start_rad - ang).rem_euclid(TAU)
                };
                if rel <= sweep_rad.abs() {
                    (dist(q_mm, centre_mm) - radius_mm).abs()
                } else {
                    dist(q_mm, from_mm).min(dist(q_mm, to_mm))
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arcs_run_the_right_way_with_their_tangents_and_curvature() {
        // A quarter counter-clockwise from (10, 0) about the origin.
        let a = Segment::arc([10.0, 0.0], [0.0, 10.0], [0.0, 0.0], true).unwrap();
        assert!((a.length_mm() - 5.0 * std::f64::consts::PI).abs() < 1e-12);
        let m = a.at(a.length_mm() / 2.0);
        let r = 10.0 / 2f64.sqrt();
        assert!((m.position_mm[0] - r).abs() < 1e-12 && (m.position_mm[1] - r).abs() < 1e-12);
        assert!((m.curvature_per_mm - 0.1).abs() < 1e-15);
        // The same ends clockwise: three quarters.
        let b = Segment::arc([10.0, 0.0], [0.0, 10.0], [0.0, 0.0], false).unwrap();
        assert!((b.length_mm() - 15.0 * std::f64::consts::PI).abs() < 1e-12);
        let (lo, hi) = b.bounds_mm();
        assert_eq!((lo, hi), ([-10.0, -10.0], [10.0, 10.0]));
        assert_eq!(a.bounds_mm(), ([0.0, 0.0], [10.0, 10.0]));
        // A full circle.
        let c = Segment::arc([10.0, 0.0], [10.0, 0.0], [0.0, 0.0], false).unwrap();
        assert!((c.length_mm() - 20.0 * std::f64::consts::PI).abs() < 1e-12);
        assert!(c.curvature_per_mm() < 0.0);
        // The centripetal acceleration points to the centre both ways.
        for s in [&a, &b] {
            let p = s.at(1.0);
            let (_, acc, _) = p.motion(100.0, 0.0, 0.0);
            let to_centre = [-p.position_mm[0], -p.position_mm[1]];
            assert!(acc[0] * to_centre[0] + acc[1] * to_centre[1] > 0.0);
            assert!((acc[0].hypot(acc[1]) - 1000.0).abs() < 1e-9);
        }
    }

    #[test]
    fn derivatives_are_the_derivatives_along_an_arc() {
        // s(t) = t³: check v, a, j against finite differences of the position.
        let arc = Segment::arc([5.0, 0.0], [-5.0, 0.0], [0.0, 0.0], false).unwrap();
        let pos = |t: f64| arc.at(t * t * t).position_mm;
        let t = 1.3;
        let h = 1e-4;
        let (v, a, j) = arc.at(t * t * t).motion(3.0 * t * t, 6.0 * t, 6.0);
        for i in 0..2 {
            let fd1 = (pos(t + h)[i] - pos(t - h)[i]) / (2.0 * h);
            let fd2 = (pos(t + h)[i] - 2.0 * pos(t)[i] + pos(t - h)[i]) / (h * h);
            let fd3 = (pos(t + 2.0 * h)[i] - 2.0 * pos(t + h)[i] + 2.0 * pos(t - h)[i]
                - pos(t - 2.0 * h)[i])
                / (2.0 * h * h * h);
            assert!((fd1 - v[i]).abs() < 1e-6, "v");
            assert!((fd2 - a[i]).abs() < 1e-4, "a");
            assert!((fd3 - j[i]).abs() < 1e-1, "j {fd3} {}", j[i]);
        }
    }

    #[test]
    fn distances_to_lines_and_arcs() {
        let l = Segment::line([0.0, 0.0], [10.0, 0.0]);
        assert_eq!(l.distance_mm([5.0, 2.0]), 2.0);
        assert_eq!(l.distance_mm([13.0, 4.0]), 5.0);
        let a = Segment::arc([10.0, 0.0], [0.0, 10.0], [0.0, 0.0], true).unwrap();
        assert!((a.distance_mm([7.0, 7.0]) - (10.0 - 98f64.sqrt())).abs() < 1e-12);
        // Outside the sweep: the nearer end.
        assert!((a.distance_mm([0.0, -10.0]) - 200f64.sqrt()).abs() < 1e-12);
    }
}
