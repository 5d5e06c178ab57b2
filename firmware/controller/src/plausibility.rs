//! Whether a calibration image of this machine carries only what a calibration of it can need:
//! a CRC proves the bytes arrived, not that they are sane. Checked at boot and at an upload's
//! commit, after the "same machine" check ([`crate::calibration`]), by [`ImageLimits::check`].
//!
//! | what | limit | derived from |
//! |---|---|---|
//! | every node correction `|δθ|` | `max_correction_rad` = 2 · `max_length_deviation_mm` / the shortest nominal link (0.0267 rad on the paper's machine) | what a model as far from the nominal as the machine's tolerance lets it be leaves to correct |
//! | neighbouring nodes' difference per mm of grid step | `max_correction_rad` / 10 mm (2.67e-3 rad/mm) | the whole correction range may not be crossed in less than 10 mm |
//! | the slope's change from one cell to the next, `|δ(i+1) − 2δ(i) + δ(i−1)| / step` | [`MAX_REFERENCE_SPEED_STEP_RAD_S`] / `servo.max_speed_mm_s` (3.3e-5 rad/mm) | a move across the grid at the servo's top speed changes the reference speed by at most 0.1 rad/s at a cell boundary: at most 1 N·m through the derivative gain (`kd` 10.4 N·m·s/rad) |
//! | the dynamics' mass matrix over the workspace (a lattice of at most 9 × 9 grid nodes, edges included, inside it and reached by the model) | each diagonal term within a factor [`INERTIA_FACTOR`] of the servo's nominal joint inertia (`AxisGains::inertia_ff_kg_m2`, 7.4e-3 kg·m²: 1.85e-3 to 2.96e-2), determinant positive | the machine the gains were tuned for; a mass matrix that is not positive definite is no mechanism |
//! | viscous friction | half the torque limit at the encoder check's top speed (0.04 N·m·s/rad) | what the drives could feed forward |
//! | Coulomb friction | a quarter of the torque limit (2 N·m) | the same |
//! | backlash `β` per drive | a tenth of `max_correction_rad` (2.67e-3 rad, 0.4 mm at a 150 mm link) | a play of that size is a broken drive, not one to compensate (the paper's plant: 2e-5 rad) |
//! | workspace polygon | every vertex reachable by the image's model at the servo's singularity margin | a stop must be able to end there |
//!
//! A refusal names the parameter, its value and the limit ([`Implausible`]); the host link
//! carries them (`CalibrationRefusal::Implausible`). The real grids of the paper's machine
//! (host-sim's `demo`, its command-by-command workflow) sit far inside: corrections up to
//! 5e-5 rad, neighbour differences 1.1e-5 rad per 5 mm, slope changes 6e-7 rad/mm; the QEMU
//! board's synthetic image reaches 3.9e-4 rad, 7.8e-6 rad/mm and 9.3e-7 rad/mm.
use kinematics_core::{CorrectionGrid, FiveBar, FiveBarDynamics, ServoConfig};
use link_protocol::ImageParameter;

/// The reference speed step a move across the grid at the servo's top speed may meet at a cell
/// boundary (rad/s): the slope-change limit is this over `ServoConfig::max_speed_mm_s`.
pub const MAX_REFERENCE_SPEED_STEP_RAD_S: f32 = 0.1;
/// The factor the image's mass matrix diagonal may be off the servo's nominal inertia.
pub const INERTIA_FACTOR: f32 = 4.0;
/// The mass matrix is checked at no more than this many nodes along each axis of the grid.
pub const DYNAMICS_LATTICE: u16 = 8;
/// The whole correction range may not be crossed in less than this (mm).
pub const MIN_CORRECTION_SPAN_MM: f32 = 10.0;

/// What an image was refused for: `parameter` is `value`, beyond `limit`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Implausible {
    /// What is out of bounds.
    pub parameter: ImageParameter,
    /// Its value (the parameter's unit).
    pub value: f32,
    /// The bound it exceeds.
    pub limit: f32,
}

impl core::fmt::Display for Implausible {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "implausible image: {:?} is {}, the limit {}",
            self.parameter, self.value, self.limit
        )
    }
}

/// The limits of the module's table, for one machine and servo.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImageLimits {
    /// Largest node correction (rad).
    pub max_correction_rad: f32,
    /// Largest neighbouring nodes' difference per mm of grid step (rad/mm).
    pub max_neighbour_rad_per_mm: f32,
    /// Largest change of the correction's slope from one cell to the next (rad/mm).
    pub max_slope_change_rad_per_mm: f32,
    /// The mass matrix's diagonal range (kg·m²).
    pub inertia_kg_m2: [f32; 2],
    /// Largest viscous friction (N·m·s/rad).
    pub max_viscous_nm_s_per_rad: f32,
    /// Largest Coulomb friction (N·m).
    pub max_coulomb_nm: f32,
    /// Largest backlash per drive (rad).
    pub max_backlash_rad: f32,
    /// The servo's singularity margin, for the reach checks.
    pub min_transmission: f32,
}

impl ImageLimits {
    /// The limits for `nominal` with its link-length tolerance `max_length_deviation_mm`, the
    /// servo `servo` and the encoder check's top speed `max_speed_rad_s` (module doc).
    pub fn of(
        nominal: &FiveBar<f32>,
        max_length_deviation_mm: f32,
        servo: &ServoConfig,
        max_speed_rad_s: f32,
    ) -> Self {
        let shortest = nominal
            .a_mm
            .min(nominal.b_mm)
            .min(nominal.c_mm)
            .min(nominal.d_mm);
        let max_correction_rad = 2.0 * max_length_deviation_mm / shortest;
        let inertia = servo.axes.map(|a| a.inertia_ff_kg_m2);
        let torque_limit = servo.axes[0]
            .torque_limit_nm
            .min(servo.axes[1].torque_limit_nm);
        ImageLimits {
            max_correction_rad,
            max_neighbour_rad_per_mm: max_correction_rad / MIN_CORRECTION_SPAN_MM,
            max_slope_change_rad_per_mm: MAX_REFERENCE_SPEED_STEP_RAD_S / servo.max_speed_mm_s,
            inertia_kg_m2: [
                inertia[0].min(inertia[1]) / INERTIA_FACTOR,
                inertia[0].max(inertia[1]) * INERTIA_FACTOR,
            ],
            max_viscous_nm_s_per_rad: 0.5 * torque_limit / max_speed_rad_s,
            max_coulomb_nm: 0.25 * torque_limit,
            max_backlash_rad: max_correction_rad / 10.0,
            min_transmission: servo.min_transmission,
        }
    }

    /// Every check of the module's table on `grid`, in its order; the first refusal.
    pub fn check(&self, grid: &CorrectionGrid<'_>) -> Result<(), Implausible> {
        self.check_nodes(grid)?;
        if let Some(d) = grid.dynamics() {
            self.check_dynamics(grid, d)?;
        }
        if let Some(b) = grid.backlash() {
            let beta = b.beta_rad();
            within(
                ImageParameter::BacklashRad,
                beta[0].max(beta[1]),
                self.max_backlash_rad,
            )?;
        }
        if let Some(w) = grid.workspace() {
            for v in w.region.vertices_mm() {
                if grid.model().inverse(*v, self.min_transmission).is_err() {
                    return Err(Implausible {
                        parameter: ImageParameter::WorkspaceVertexXMm,
                        value: v[0],
                        limit: v[0],
                    });
                }
            }
        }
        Ok(())
    }

    /// Magnitude, neighbour differences and slope changes of the node corrections.
    fn check_nodes(&self, grid: &CorrectionGrid<'_>) -> Result<(), Implausible> {
        let g = *grid.geometry();
        let node = |i: u16, j: u16| grid.node_rad(i, j);
        let (mut largest, mut neighbour, mut slope) = (0.0f32, 0.0f32, 0.0f32);
        // `!(a <= b)`: NaN counts as the largest (the parser refuses it anyway).
        let keep = |m: &mut f32, v: f32| {
            if !(v <= *m) {
                *m = v
            }
        };
        for j in 0..g.ny {
            for i in 0..g.nx {
                let d = node(i, j);
                #[allow(clippy::needless_range_loop)]
                // k indexes the node, its neighbours and the axis
                for k in 0..2 {
                    keep(&mut largest, d[k].abs());
                    if i + 1 < g.nx {
                        let next = node(i + 1, j)[k];
                        keep(&mut neighbour, (next - d[k]).abs() / g.step_x_mm);
                        if i > 0 {
                            let second = next - 2.0 * d[k] + node(i - 1, j)[k];
                            keep(&mut slope, second.abs() / g.step_x_mm);
                        }
                    }
                    if j + 1 < g.ny {
                        let next = node(i, j + 1)[k];
                        keep(&mut neighbour, (next - d[k]).abs() / g.step_y_mm);
                        if j > 0 {
                            let second = next - 2.0 * d[k] + node(i, j - 1)[k];
                            keep(&mut slope, second.abs() / g.step_y_mm);
                        }
                    }
                }
            }
        }
        within(
            ImageParameter::NodeCorrectionRad,
            largest,
            self.max_correction_rad,
        )?;
        within(
            ImageParameter::NeighbourDifferenceRadPerMm,
            neighbour,
            self.max_neighbour_rad_per_mm,
        )?;
        within(
            ImageParameter::SlopeChangeRadPerMm,
            slope,
            self.max_slope_change_rad_per_mm,
        )
    }

    /// Friction, then the mass matrix at the lattice's nodes inside the workspace (the whole
    /// grid without a workspace block) that the model reaches.
    fn check_dynamics(
        &self,
        grid: &CorrectionGrid<'_>,
        d: &FiveBarDynamics<f32>,
    ) -> Result<(), Implausible> {
        let viscous = d.viscous_nm_s_per_rad[0].max(d.viscous_nm_s_per_rad[1]);
        within(
            ImageParameter::ViscousNmSPerRad,
            viscous,
            self.max_viscous_nm_s_per_rad,
        )?;
        let coulomb = d.coulomb_nm[0].max(d.coulomb_nm[1]);
        within(ImageParameter::CoulombNm, coulomb, self.max_coulomb_nm)?;
        let g = *grid.geometry();
        let region = grid.workspace().map(|w| w.region);
        let [low, high] = self.inertia_kg_m2;
        // A lattice of at most DYNAMICS_LATTICE² nodes, edges included: the mass matrix varies
        // over tens of millimetres, and the check must stay cheap where it runs (a boot, a
        // commit, the QEMU harness's own reading of the slots inside a servo sample).
        let stride = |n: u16| n.div_ceil(DYNAMICS_LATTICE).max(1);
        let lattice = |n: u16| {
            let s = stride(n);
            (0..n).filter(move |k| k % s == 0 || *k == n - 1)
        };
        for j in lattice(g.ny) {
            for i in lattice(g.nx) {
                let p = g.node_mm(i, j);
                if region.is_some_and(|r| !r.contains(p, 0.0)) {
                    continue;
                }
                let Ok(pose) = grid.model().inverse_pose(p, self.min_transmission) else {
                    continue;
                };
                let Ok((m, _)) = d.mass_matrix_and_bias(&pose, [0.0; 2]) else {
                    continue;
                };
                for diagonal in [m[0][0], m[1][1]] {
                    within(ImageParameter::InertiaHighKgM2, diagonal, high)?;
                    if !(diagonal >= low) {
                        return Err(Implausible {
                            parameter: ImageParameter::InertiaLowKgM2,
                            value: diagonal,
                            limit: low,
                        });
                    }
                }
                let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
                if !(det > 0.0) {
                    return Err(Implausible {
                        parameter: ImageParameter::MassMatrixDeterminant,
                        value: det,
                        limit: 0.0,
                    });
                }
            }
        }
        Ok(())
    }
}

/// `value` at most `limit` (NaN refused).
fn within(parameter: ImageParameter, value: f32, limit: f32) -> Result<(), Implausible> {
    if value <= limit {
        Ok(())
    } else {
        Err(Implausible {
            parameter,
            value,
            limit,
        })
    }
}

#[cfg(test)]
mod tests;
