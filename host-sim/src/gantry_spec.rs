//! The x-y gantry that carries the micro-mechanism on a redundant laser-cutting machine: its
//! travel, per-axis limits and the dynamics of its axes (the machine file's optional
//! `[gantry]` section, `host-sim/MACHINE.md`), and how the split planner shares the work with
//! the micro (`micro_*` keys).
//!
//! Defaults ([`GantrySpec::paper`]): the paper's heavy cantilever gantry (Kiper et al.,
//! introduction: 1.5 m × 3.0 m travel; its limits 1 g, 1.5 m/s and 200 m/s³ per axis). No
//! better-founded figures for that machine were found, so these stand; a lighter modern bridge
//! is a `[gantry]` section with its own numbers. The axes' dynamics (moving masses, friction,
//! position-loop bandwidth, feed-forward error, scale resolution) are typical of a gantry of
//! that class, chosen so that the simulated following error is what such a machine shows (tens
//! of µm at 1 g): what the micro has to compensate.

/// The gantry and the split's settings (see the module doc; keys in `host-sim/MACHINE.md`).
#[derive(Clone, Debug, PartialEq)]
pub struct GantrySpec {
    /// Travel of the x axis `[low, high]` (mm): where the micro's workspace centre can be.
    pub travel_x_mm: [f64; 2],
    /// Travel of the y axis `[low, high]` (mm).
    pub travel_y_mm: [f64; 2],
    /// Where the gantry rests when a program starts (mm), the micro at its workspace centre.
    pub home_mm: [f64; 2],
    /// Largest speed of each axis (mm/s).
    pub speed_mm_s: f64,
    /// Largest acceleration of each axis (g).
    pub accel_g: f64,
    /// Largest jerk of each axis (mm/s³).
    pub jerk_mm_s3: f64,
    /// Position-loop bandwidth of each axis (Hz).
    pub bandwidth_hz: f64,
    /// Moving mass of the x axis (bridge, y carriage, micro) and of the y axis (kg).
    pub moving_mass_kg: [f64; 2],
    /// Coulomb friction of each axis (N).
    pub friction_n: [f64; 2],
    /// Error of the mass the drives feed forward (%): the model error that leaves a following
    /// error at every acceleration.
    pub feedforward_mass_error_pct: f64,
    /// Resolution of each axis' linear scale (µm).
    pub scale_resolution_um: f64,
    /// How far inside its workspace the split keeps the micro (mm).
    pub micro_margin_mm: f64,
    /// The micro's largest joint speed (rad/s).
    pub micro_joint_speed_rad_s: f64,
}

impl GantrySpec {
    /// The paper's gantry (see the module doc); `host-sim/machines/paper.toml` states it.
    pub fn paper() -> Self {
        GantrySpec {
            travel_x_mm: [0.0, 1500.0],
            travel_y_mm: [0.0, 3000.0],
            home_mm: [0.0, 0.0],
            speed_mm_s: 1500.0,
            accel_g: 1.0,
            jerk_mm_s3: 200_000.0,
            bandwidth_hz: 30.0,
            moving_mass_kg: [450.0, 90.0],
            friction_n: [150.0, 30.0],
            feedforward_mass_error_pct: 5.0,
            scale_resolution_um: 0.05,
            micro_margin_mm: 2.0,
            // A servo motor's 3000 rpm through the drives' 10:1 gearing.
            micro_joint_speed_rad_s: 31.4,
        }
    }

    /// Whether `p_mm` lies within the travel (edges included).
    pub fn in_travel(&self, p_mm: [f64; 2]) -> bool {
        p_mm[0] >= self.travel_x_mm[0]
            && p_mm[0] <= self.travel_x_mm[1]
            && p_mm[1] >= self.travel_y_mm[0]
            && p_mm[1] <= self.travel_y_mm[1]
    }

    /// Every value finite and in range; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        for (key, r) in [
            ("gantry.travel_x_mm", self.travel_x_mm),
            ("gantry.travel_y_mm", self.travel_y_mm),
        ] {
            if !(r[0].is_finite() && r[1].is_finite() && r[1] > r[0] && r[1] - r[0] <= 1e5) {
                return Err(format!(
                    "'{key}' must be [low, high] with low < high within 100 m, not {r:?}"
                ));
            }
        }
        if !self.in_travel(self.home_mm) {
            return Err(format!(
                "'gantry.home_mm' {:?} lies outside the travel",
                self.home_mm
            ));
        }
        let ranges = [
            ("gantry.speed_mm_s", self.speed_mm_s, 1.0, 20_000.0),
            ("gantry.accel_g", self.accel_g, 0.01, 10.0),
            ("gantry.jerk_mm_s3", self.jerk_mm_s3, 1e3, 1e9),
            ("gantry.bandwidth_hz", self.bandwidth_hz, 1.0, 200.0),
            ("gantry.moving_mass_kg[0]", self.moving_mass_kg[0], 0.1, 1e5),
            ("gantry.moving_mass_kg[1]", self.moving_mass_kg[1], 0.1, 1e5),
            ("gantry.friction_n[0]", self.friction_n[0], 0.0, 1e5),
            ("gantry.friction_n[1]", self.friction_n[1], 0.0, 1e5),
            (
                "gantry.feedforward_mass_error_pct",
                self.feedforward_mass_error_pct,
                -50.0,
                50.0,
            ),
            (
                "gantry.scale_resolution_um",
                self.scale_resolution_um,
                0.0,
                100.0,
            ),
            ("gantry.micro_margin_mm", self.micro_margin_mm, 0.0, 1e3),
            (
                "gantry.micro_joint_speed_rad_s",
                self.micro_joint_speed_rad_s,
                0.1,
                1e4,
            ),
        ];
        for (key, v, lo, hi) in ranges {
            if !(v >= lo && v <= hi) {
                return Err(format!("'{key}' must be in [{lo}, {hi}], not {v}"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_gantry_is_valid_and_bad_values_are_named() {
        assert_eq!(GantrySpec::paper().validate(), Ok(()));
        let mut g = GantrySpec::paper();
        g.accel_g = f64::NAN;
        assert!(g.validate().unwrap_err().contains("gantry.accel_g"));
        let mut g = GantrySpec::paper();
        g.travel_y_mm = [10.0, 0.0];
        assert!(g.validate().unwrap_err().contains("gantry.travel_y_mm"));
        let mut g = GantrySpec::paper();
        g.home_mm = [-1.0, 0.0];
        assert!(g.validate().unwrap_err().contains("gantry.home_mm"));
    }
}
