//! Every number of a machine description against its physical meaning, checked when the
//! machine file is read ([`MachineSpec::validate`](crate::machine_spec::MachineSpec::validate)).
//!
//! Why beyond "finite and positive": a value in no real machine's range is a typo or a unit
//! mistake, and it fails late and far from its cause (`approach.distance_mm = 1e300` made
//! `plan` write approach starts at 7.8e299 mm; `stop_margin_mm = 80` left the firmware no
//! workspace, so it faulted at rest; `sigma_um = 1e300` failed inside `demo`). Each limit
//! below says what it protects; the refusal names the key, its value and the limit. The
//! limits are stated in `host-sim/MACHINE.md`.

use super::MachineSpec;

/// The largest link length, base coordinate or workspace coordinate (mm): a 10 m mechanism is
/// no micro-mechanism, and a metres value typed as mm (0.15 for 150) is caught by the reach
/// check.
pub const MAX_LENGTH_MM: f64 = 10_000.0;
/// The largest |encoder zero offset| (°): one turn; more is the same offset written twice.
pub const MAX_ZERO_OFFSET_DEG: f64 = 360.0;
/// The approach move may be at most this fraction of the workspace's smaller side: it starts
/// that far from every measured pose, which must stay near the workspace.
pub const MAX_APPROACH_FRACTION: f64 = 0.25;
/// The stop margin may be at most this fraction of the distance from the workspace's centre to
/// its nearest edge: a controlled stop must end inside, and half the workspace must remain.
pub const MAX_STOP_MARGIN_FRACTION: f64 = 0.5;
/// The largest instrument σ (µm): a calibration instrument resolves better than a millimetre
/// (laser trackers ~10 µm, interferometers < 1 µm); above, the grid corrects noise.
pub const MAX_SIGMA_UM: f64 = 1000.0;
/// The servo's sample period range (s): 100 kHz to 100 Hz.
pub const SAMPLE_PERIOD_RANGE_S: [f64; 2] = [1e-5, 1e-2];
/// The largest rated acceleration (g).
pub const MAX_ACCELERATION_G: f64 = 100.0;
/// The largest singularity margin (|sin| of a transmission angle): above, almost no pose is
/// commandable.
pub const MAX_MIN_TRANSMISSION: f64 = 0.9;
/// The smallest grid step (mm): finer than a tracker's repeatability is no correction.
pub const MIN_GRID_STEP_MM: f64 = 0.1;

/// The checks (module doc); the message names the machine file's key.
pub fn check(spec: &MachineSpec) -> Result<(), String> {
    let m = &spec.nominal;
    let within = |key: &str, v: f64, lo: f64, hi: f64, why: &str| {
        if v.is_finite() && v >= lo && v <= hi {
            Ok(())
        } else {
            Err(format!("'{key}' = {v} is out of range [{lo}, {hi}]: {why}"))
        }
    };
    let length = "longer than any machine this tool is for (10 m)";
    for (key, v) in [
        ("nominal.a_mm", m.a_mm),
        ("nominal.b_mm", m.b_mm),
        ("nominal.c_mm", m.c_mm),
        ("nominal.d_mm", m.d_mm),
    ] {
        within(key, v, f64::MIN_POSITIVE, MAX_LENGTH_MM, length)?;
    }
    let b0 = [
        m.base_a0_mm[0] + m.base_b0_mm[0],
        m.base_a0_mm[1] + m.base_b0_mm[1],
    ];
    for (key, v) in [("nominal.a0_mm", m.base_a0_mm), ("nominal.b0_mm", b0)] {
        for x in v {
            within(key, x, -MAX_LENGTH_MM, MAX_LENGTH_MM, length)?;
        }
    }
    for o in m.encoder_offset_rad {
        within(
            "encoders.zero_offset_deg",
            o.to_degrees(),
            -MAX_ZERO_OFFSET_DEG,
            MAX_ZERO_OFFSET_DEG,
            "more than a turn",
        )?;
    }
    let ws = &spec.workspace;
    let side_mm = (ws.x_mm[1] - ws.x_mm[0]).min(ws.y_mm[1] - ws.y_mm[0]);
    within(
        "approach.distance_mm",
        spec.approach_mm,
        f64::MIN_POSITIVE,
        MAX_APPROACH_FRACTION * side_mm,
        &format!(
            "the approach starts this far from every measured pose; at most a quarter of the workspace's smaller side ({side_mm} mm)"
        ),
    )?;
    let centre = ws.centre_mm();
    let inside_mm = edge_distance_mm(ws.region.vertices_mm(), centre);
    within(
        "workspace.stop_margin_mm",
        ws.stop_margin_mm,
        0.0,
        MAX_STOP_MARGIN_FRACTION * inside_mm,
        &format!(
            "a controlled stop ends this far inside the workspace; the centre ({:.3}, {:.3}) mm is {inside_mm:.3} mm from the nearest edge, and at most half of that may be margin or no workspace is left",
            centre[0], centre[1]
        ),
    )?;
    within(
        "instrument.sigma_um",
        spec.instrument_sigma_um,
        0.0,
        MAX_SIGMA_UM,
        "a calibration instrument's noise σ per axis; no instrument that calibrates is worse than 1 mm",
    )?;
    within(
        "servo.sample_period_s",
        spec.sample_period_s,
        SAMPLE_PERIOD_RANGE_S[0],
        SAMPLE_PERIOD_RANGE_S[1],
        "a servo runs between 100 Hz and 100 kHz (the firmware's: 0.0005 s)",
    )?;
    within(
        "servo.max_acceleration_g",
        spec.max_acceleration_g,
        f64::MIN_POSITIVE,
        MAX_ACCELERATION_G,
        "the machine's rated acceleration",
    )?;
    within(
        "servo.min_transmission",
        spec.min_transmission,
        f64::MIN_POSITIVE,
        MAX_MIN_TRANSMISSION,
        "the smallest |sin| of a transmission angle commanded; above 0.9 almost no pose is left",
    )?;
    within(
        "grid.step_mm",
        spec.grid.step_mm,
        MIN_GRID_STEP_MM,
        side_mm,
        "the correction grid's node spacing, between 0.1 mm and the workspace's smaller side",
    )?;
    Ok(())
}

/// The distance from `p` (inside) to the nearest edge of the convex polygon `v`.
fn edge_distance_mm(v: &[[f64; 2]], p: [f64; 2]) -> f64 {
    (0..v.len())
        .map(|k| {
            let (a, b) = (v[k], v[(k + 1) % v.len()]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            ((p[0] - a[0]) * dy - (p[1] - a[1]) * dx).abs() / dx.hypot(dy)
        })
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_machines_are_in_range_and_absurd_values_are_not() {
        let paper = MachineSpec::paper();
        check(&paper).unwrap();
        let second =
            crate::io::machine_file::parse_machine(include_str!("../../machines/second.toml"))
                .unwrap();
        check(&second).unwrap();
        let refused = |edit: &dyn Fn(&mut MachineSpec), key: &str| {
            let mut s = MachineSpec::paper();
            edit(&mut s);
            let e = check(&s).unwrap_err();
            assert!(e.starts_with(&format!("'{key}'")), "{e}");
        };
        refused(&|s| s.approach_mm = 1e300, "approach.distance_mm");
        refused(&|s| s.approach_mm = 26.0, "approach.distance_mm");
        refused(
            &|s| s.workspace.stop_margin_mm = 80.0,
            "workspace.stop_margin_mm",
        );
        refused(
            &|s| s.workspace.stop_margin_mm = 25.1,
            "workspace.stop_margin_mm",
        );
        refused(&|s| s.instrument_sigma_um = 1e300, "instrument.sigma_um");
        refused(&|s| s.sample_period_s = 5.0, "servo.sample_period_s");
        refused(&|s| s.max_acceleration_g = 1e4, "servo.max_acceleration_g");
        refused(&|s| s.nominal.a_mm = 1e7, "nominal.a_mm");
        refused(
            &|s| s.nominal.encoder_offset_rad[0] = 7.0,
            "encoders.zero_offset_deg",
        );
        refused(&|s| s.min_transmission = 0.95, "servo.min_transmission");
        // The paper's centre is 50 mm from its nearest edge: 25 mm of margin is the limit.
        let mut s = MachineSpec::paper();
        s.workspace.stop_margin_mm = 25.0;
        check(&s).unwrap();
    }
}
