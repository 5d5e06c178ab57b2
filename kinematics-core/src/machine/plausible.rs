//! "Is this image a plausible calibration of this machine?": the content of an image that
//! parses (CRC, format, finite numbers) judged against what the machine can need
//! ([`super::PlausibilityLimits`]; `docs/reference/calibration-image.md` derives each limit).
//!
//! # The checks, in order
//! 1. The home position lies in the grid (the controller starts there).
//! 2. The workspace block, if any, lies inside the machine's workspace (to 1 µm, the f32
//!    rounding of a vertex).
//! 3. The backlash block, if any: each drive's lost motion at most `max_backlash_rad`.
//! 4. The dynamics block, if any: viscous and Coulomb friction at most `dynamics_factor` times
//!    the nominal's, the Coulomb speed within that factor of it; at every workspace lattice
//!    point a positive-definite mass matrix `M` whose generalised eigenvalues against the
//!    nominal's `M₀` (`det(M − λ·M₀) = 0`: the kinetic energy of the worst joint motion over
//!    the nominal's for the same motion) lie within `[1/factor, factor]`. Each `M` at the pose
//!    its own model (the image's, the nominal) has for the point.
//! 5. Every node: the image's model reaches it; its correction `δθ` moves the tool by
//!    `|J·δθ| ≤ max_node_correction_mm` (`J` the image's model's Jacobian at the node); with
//!    each neighbour along x and y, `|J·(δθ' − δθ)| / distance ≤ max_correction_slope`.
//!
//! # Cost
//! Per node one IK with the pose and one Jacobian (about 420 instructions on the Cortex-M4F):
//! 0.27 M instructions for the paper's 651 nodes (1.6 ms at 170 MHz), proportional to the node
//! count. The dynamics: two mass matrices per lattice point (three inverse dynamics each), about
//! 0.1 M instructions. Run at an image's commit and at boot, never in the servo's sample.

use super::lattice::workspace_points;
use super::record::MachineRecord;
use super::refusal::Implausible;
use crate::dynamics::{FiveBarDynamics, PARAMETER_NAMES};
use crate::grid::CorrectionGrid;
use crate::jacobian::{mat2_mul_vec, Mat2};
use crate::model::FiveBar;
use crate::real::Real;

/// How far outside the machine's workspace an image's vertex may lie (mm): f32 rounding.
pub const WORKSPACE_TOLERANCE_MM: f32 = 1.0e-3;

/// How close an accepted image came to its limits: the largest value of each judged quantity.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Margins {
    /// The largest tool displacement of a node's correction (mm).
    pub correction_mm: f32,
    /// The largest change of it between neighbours per mm.
    pub correction_slope: f32,
    /// The smallest and largest kinetic-energy ratio against the nominal dynamics over the
    /// workspace, if the image carries dynamics.
    pub inertia_ratio: Option<[f32; 2]>,
}

/// The checks of the module doc, first failure returned; on success how close the image came
/// to each limit.
pub fn plausible(
    grid: &CorrectionGrid<'_>,
    record: &MachineRecord,
) -> Result<Margins, Implausible> {
    let limits = &record.limits;
    if grid.correction_rad(record.home_mm).is_err() {
        return Err(Implausible::HomeOutsideGrid {
            home_mm: record.home_mm,
        });
    }
    if let Some(w) = grid.workspace() {
        for v in w.region.vertices_mm() {
            let outside_mm = -record.workspace.region.clearance_mm(*v);
            if !(outside_mm <= WORKSPACE_TOLERANCE_MM) {
                return Err(Implausible::Workspace {
                    vertex_mm: *v,
                    outside_mm,
                });
            }
        }
    }
    if let Some(b) = grid.backlash() {
        for (axis, beta) in b.beta_rad().iter().enumerate() {
            if !(*beta <= limits.max_backlash_rad) {
                return Err(Implausible::Backlash {
                    axis: axis as u8,
                    image_rad: *beta,
                    limit_rad: limits.max_backlash_rad,
                });
            }
        }
    }
    let inertia_ratio = match grid.dynamics() {
        Some(d) => Some(dynamics_plausible(d, grid.model(), record)?),
        None => None,
    };
    let [correction_mm, correction_slope] = nodes_plausible(grid, record)?;
    Ok(Margins {
        correction_mm,
        correction_slope,
        inertia_ratio,
    })
}

/// Check 4 of the module doc; the smallest and largest energy ratio found.
fn dynamics_plausible(
    d: &FiveBarDynamics<f32>,
    model: &FiveBar<f32>,
    record: &MachineRecord,
) -> Result<[f32; 2], Implausible> {
    let nominal = &record.limits.nominal_dynamics;
    let factor = record.limits.dynamics_factor;
    let (image_p, nominal_p) = (d.to_array(), nominal.to_array());
    // Friction: parameters 5..9 (viscous, Coulomb), at most the factor times the nominal's.
    for k in 5..image_p.len() {
        if !(image_p[k] <= factor * nominal_p[k]) {
            return Err(Implausible::Friction {
                parameter: PARAMETER_NAMES[k],
                image: image_p[k],
                nominal: nominal_p[k],
                factor,
            });
        }
    }
    let (w, w0) = (d.coulomb_speed_rad_s, nominal.coulomb_speed_rad_s);
    if !(w >= w0 / factor && w <= w0 * factor) {
        return Err(Implausible::Friction {
            parameter: "coulomb_speed_rad_s",
            image: w,
            nominal: w0,
            factor,
        });
    }
    let (points, n) = workspace_points(&record.workspace.region);
    let mut range = [f32::INFINITY, 0.0f32];
    for p in &points[..n] {
        let (Ok(pose), Ok(pose0)) = (
            model.inverse_pose(*p, 0.0),
            record.nominal.inverse_pose(*p, 0.0),
        ) else {
            return Err(Implausible::Unreachable { at_mm: *p });
        };
        let m0 = match nominal.mass_matrix_and_bias(&pose0, [0.0; 2]) {
            Ok((m, _)) if positive_definite(&m) => m,
            _ => return Err(Implausible::NominalDynamics { at_mm: *p }),
        };
        let m = match d.mass_matrix_and_bias(&pose, [0.0; 2]) {
            Ok((m, _)) if positive_definite(&m) => m,
            _ => return Err(Implausible::MassMatrix { at_mm: *p }),
        };
        let [lo, hi] = generalised_eigenvalues(&m, &m0);
        for ratio in [hi, lo] {
            if !(ratio <= factor && ratio >= 1.0 / factor) {
                return Err(Implausible::Inertia {
                    at_mm: *p,
                    ratio,
                    factor,
                });
            }
        }
        range = [range[0].min(lo), range[1].max(hi)];
    }
    Ok(range)
}

/// Whether a (symmetrised) 2×2 matrix is positive definite: `m₀₀ > 0` and `det > 0`.
fn positive_definite(m: &Mat2<f32>) -> bool {
    let off = 0.5 * (m[0][1] + m[1][0]);
    m[0][0] > 0.0 && m[0][0] * m[1][1] - off * off > 0.0
}

/// The roots `λ` of `det(A − λ·B) = 0`, smaller first, for symmetric `A` and positive-definite
/// `B` (both symmetrised): `det B·λ² − (a₀₀b₁₁ + a₁₁b₀₀ − 2a₀₁b₀₁)·λ + det A = 0`. They are
/// the extreme ratios `vᵀAv / vᵀBv` over joint motions `v`.
fn generalised_eigenvalues(a: &Mat2<f32>, b: &Mat2<f32>) -> [f32; 2] {
    let (a01, b01) = (0.5 * (a[0][1] + a[1][0]), 0.5 * (b[0][1] + b[1][0]));
    let det_b = b[0][0] * b[1][1] - b01 * b01;
    let t = a[0][0] * b[1][1] + a[1][1] * b[0][0] - 2.0 * a01 * b01;
    // The discriminant `t² − 4·det A·det B` written without its cancellation (the same
    // polynomial expanded): when `A` is close to a multiple of `B` (both roots equal) the
    // direct form loses half the digits (4e-4 relative in f32), this one keeps them.
    let u = a[0][0] * b[1][1] - a[1][1] * b[0][0];
    let disc = u * u + 4.0 * (a[0][0] * b01 - a01 * b[0][0]) * (a[1][1] * b01 - a01 * b[1][1]);
    // Real roots for a positive-definite `B`; rounding may still push it a little below 0.
    let root = if disc > 0.0 { Real::sqrt(disc) } else { 0.0 };
    [(t - root) / (2.0 * det_b), (t + root) / (2.0 * det_b)]
}

/// Check 5 of the module doc; the largest correction and slope found.
fn nodes_plausible(
    grid: &CorrectionGrid<'_>,
    record: &MachineRecord,
) -> Result<[f32; 2], Implausible> {
    let limits = &record.limits;
    let mut worst = [0.0f32; 2];
    let g = grid.geometry();
    let model = grid.model();
    let length = |v: [f32; 2]| Real::sqrt(v[0] * v[0] + v[1] * v[1]);
    for j in 0..g.ny {
        for i in 0..g.nx {
            let at_mm = g.node_mm(i, j);
            let jacobian = model
                .inverse_pose(at_mm, 0.0)
                .and_then(|pose| pose.jacobian())
                .map_err(|_| Implausible::Unreachable { at_mm })?;
            let here = grid.node_rad(i, j);
            let correction_mm = length(mat2_mul_vec(&jacobian, here));
            worst[0] = worst[0].max(correction_mm);
            if !(correction_mm <= limits.max_node_correction_mm) {
                return Err(Implausible::NodeCorrection {
                    node: [i, j],
                    correction_mm,
                    limit_mm: limits.max_node_correction_mm,
                });
            }
            let neighbours = [
                (i + 1 < g.nx).then_some(([i + 1, j], g.step_x_mm)),
                (j + 1 < g.ny).then_some(([i, j + 1], g.step_y_mm)),
            ];
            for (neighbour, step_mm) in neighbours.into_iter().flatten() {
                let there = grid.node_rad(neighbour[0], neighbour[1]);
                let change = [there[0] - here[0], there[1] - here[1]];
                let slope = length(mat2_mul_vec(&jacobian, change)) / step_mm;
                worst[1] = worst[1].max(slope);
                if !(slope <= limits.max_correction_slope) {
                    return Err(Implausible::CorrectionSlope {
                        node: [i, j],
                        neighbour,
                        slope,
                        limit: limits.max_correction_slope,
                    });
                }
            }
        }
    }
    Ok(worst)
}
