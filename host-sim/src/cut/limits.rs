//! What a machine allows along the path: each segment's speed cap and tangential acceleration
//! and jerk limits, and the speed caps at the junctions between segments, from a machine's
//! limits ([`PathLimits`]). Two machines use it: the combined tool of the split (the micro's
//! acceleration, no jerk from curvature: the micro has no jerk limit, the gantry is filtered)
//! and the gantry alone (per-axis box limits, every jerk counted).
//!
//! * **Lines** with direction `u`: per-axis limits (the gantry alone) bind along the line as
//!   `limit / max(|uₓ|, |u_y|)`; the tool's acceleration is a norm (the micro's rating), its
//!   speed a per-axis cap (the gantry's rapid rate, so the filtered gantry keeps within it).
//! * **Arcs** of radius `R`: the centripetal acceleration `v²/R` gets [`NORMAL_SHARE`] of the
//!   acceleration, the tangential the rest (`√(A² − (v²/R)²)`), so their sum stays within the
//!   norm; with curvature jerk counted, `v³/R²` gets 40 % of the jerk, the tangential jerk 30 %
//!   and the cross term `3·v·s̈/R` 30 % (`j = (s⃛ − κ²v³)·T + 3κ·v·s̈·N`).
//! * **Junctions**: a change of direction by `θ` at speed `v` is a jump of `2v·sin(θ/2)` in
//!   velocity within one servo sample; it is allowed up to `kink_dv_mm_s` (a corner is then
//!   passed at about that speed: nearly a stop). A change of curvature `Δκ` steps the
//!   acceleration by `v²·Δκ`; a jerk-limited machine allows `J·T_w` (its jerk over
//!   [`JERK_WINDOW_S`], the window the executed jerk is measured over).

use super::gcode::MoveKind;
use super::path::Segment;
use super::profile::SegmentLimits;

/// Share of the acceleration given to the centripetal part on arcs.
pub const NORMAL_SHARE: f64 = 0.8;
/// The window over which jerk is measured (s): a jerk limit holds for the change of
/// acceleration over any 2.5 ms (what a drive's current loop resolves).
pub const JERK_WINDOW_S: f64 = 0.0025;

/// A machine's limits along the path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathLimits {
    /// Speed cap of each axis (mm/s).
    pub axis_speed_mm_s: f64,
    /// Acceleration (mm/s²): per axis if `per_axis`, else of the norm.
    pub accel_mm_s2: f64,
    /// Jerk (mm/s³), the same way.
    pub jerk_mm_s3: f64,
    /// Per-axis box limits (a gantry) rather than norms (the micro).
    pub per_axis: bool,
    /// The jerk of curvature counts (`v³/R²` on arcs, acceleration steps at junctions).
    pub curvature_jerk: bool,
    /// Largest velocity jump at a junction (mm/s).
    pub kink_dv_mm_s: f64,
}

/// Local slow-down of a span (the split's reach and limit checks lower these).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scale {
    pub speed: f64,
    pub accel: f64,
}

impl Default for Scale {
    fn default() -> Self {
        Scale {
            speed: 1.0,
            accel: 1.0,
        }
    }
}

impl PathLimits {
    /// The limits of `seg` moved as `kind`, slowed by `scale`.
    pub fn segment(&self, seg: &Segment, kind: MoveKind, scale: Scale) -> SegmentLimits {
        let feed = match kind {
            MoveKind::Rapid => f64::INFINITY,
            MoveKind::Feed { feed_mm_s } => feed_mm_s,
        };
        let a = self.accel_mm_s2 * scale.accel;
        let j = self.jerk_mm_s3 * scale.accel.powf(1.5);
        let (speed, accel, jerk) = match *seg {
            Segment::Line { dir, .. } => {
                let m = dir[0].abs().max(dir[1].abs()).max(1e-12);
                let (a, j) = if self.per_axis {
                    (a / m, j / m)
                } else {
                    (a, j)
                };
                (feed.min(self.axis_speed_mm_s / m), a, j)
            }
            Segment::Arc { radius_mm: r, .. } => {
                // The norm within the per-axis speed keeps every axis within it.
                let mut v = feed
                    .min(self.axis_speed_mm_s)
                    .min((NORMAL_SHARE * a * r).sqrt());
                if self.curvature_jerk {
                    v = v.min((0.4 * j * r * r).cbrt());
                }
                let an = v * v / r;
                let mut at = (a * a - an * an).max(0.0).sqrt();
                let mut jt = j;
                if self.curvature_jerk {
                    at = at.min(0.1 * j * r / v.max(1e-9));
                    jt = 0.3 * j;
                }
                (v, at, jt)
            }
        };
        SegmentLimits {
            length_mm: seg.length_mm(),
            speed_mm_s: (speed * scale.speed).max(1e-6),
            accel_mm_s2: accel.max(1e-6),
            jerk_mm_s3: jerk.max(1e-6),
        }
    }

    /// The speed cap at the junction from `a` to `b` (mm/s; infinite for a smooth junction).
    pub fn junction(&self, a: &Segment, b: &Segment) -> f64 {
        let (_, ta) = a.tangents();
        let (tb, _) = b.tangents();
        let cos = (ta[0] * tb[0] + ta[1] * tb[1]).clamp(-1.0, 1.0);
        let half_sin = ((1.0 - cos) / 2.0).max(0.0).sqrt();
        let mut cap = if half_sin > 0.0 {
            self.kink_dv_mm_s / (2.0 * half_sin)
        } else {
            f64::INFINITY
        };
        if self.curvature_jerk {
            let dk = (a.curvature_per_mm() - b.curvature_per_mm()).abs();
            if dk > 0.0 {
                cap = cap.min((self.jerk_mm_s3 * JERK_WINDOW_S / dk).sqrt());
            }
        }
        cap
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gantry() -> PathLimits {
        PathLimits {
            axis_speed_mm_s: 1500.0,
            accel_mm_s2: 9806.65,
            jerk_mm_s3: 2e5,
            per_axis: true,
            curvature_jerk: true,
            kink_dv_mm_s: 0.2,
        }
    }

    #[test]
    fn per_axis_limits_bind_along_a_diagonal_as_the_axes_allow() {
        let g = gantry();
        let diag = Segment::line([0.0, 0.0], [100.0, 100.0]);
        let l = g.segment(&diag, MoveKind::Rapid, Scale::default());
        let r2 = 2f64.sqrt();
        assert!((l.speed_mm_s - 1500.0 * r2).abs() < 1e-9);
        assert!((l.accel_mm_s2 - 9806.65 * r2).abs() < 1e-9);
        let l = g.segment(
            &Segment::line([0.0, 0.0], [100.0, 0.0]),
            MoveKind::Feed { feed_mm_s: 100.0 },
            Scale::default(),
        );
        assert_eq!(l.speed_mm_s, 100.0);
    }

    #[test]
    fn arcs_keep_the_acceleration_and_jerk_norms() {
        let g = gantry();
        let arc = Segment::arc([10.0, 0.0], [-10.0, 0.0], [0.0, 0.0], true).unwrap();
        let l = g.segment(&arc, MoveKind::Feed { feed_mm_s: 1000.0 }, Scale::default());
        let (v, r) = (l.speed_mm_s, 10.0);
        assert!(v * v / r <= NORMAL_SHARE * 9806.65 + 1e-9);
        assert!(v.powi(3) / (r * r) <= 0.4 * 2e5 * (1.0 + 1e-12));
        let an = v * v / r;
        assert!((l.accel_mm_s2.powi(2) + an * an).sqrt() <= 9806.65 * (1.0 + 1e-12));
        assert!(l.jerk_mm_s3 + v.powi(3) / (r * r) + 3.0 * v * l.accel_mm_s2 / r <= 2e5 * 1.0001);
    }

    #[test]
    fn junction_caps_from_the_angle_and_the_curvature_step() {
        let g = gantry();
        let a = Segment::line([0.0, 0.0], [10.0, 0.0]);
        let b = Segment::line([10.0, 0.0], [10.0, 10.0]);
        let cap = g.junction(&a, &b);
        assert!((cap - 0.2 / 2f64.sqrt()).abs() < 1e-12);
        // Tangent line into an arc: only the curvature step.
        let c = Segment::arc([10.0, 0.0], [10.0, 10.0], [10.0, 5.0], true).unwrap();
        let cap = g.junction(&a, &c);
        assert!(
            (cap - (2e5 * JERK_WINDOW_S * 5.0f64).sqrt()).abs() < 1e-6,
            "{cap}"
        );
        let tool = PathLimits {
            curvature_jerk: false,
            ..g
        };
        assert_eq!(tool.junction(&a, &c), f64::INFINITY);
    }
}
