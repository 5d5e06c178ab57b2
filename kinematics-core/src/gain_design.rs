//! The servo's gains for the dynamics the controller feeds forward: one rule, used by the
//! firmware when it engages a calibration and by the host tools that predict it.
//!
//! The position loop is designed for an axis inertia `J` ([`ServoConfig::default`]: kp = J·ω²,
//! kd = 2ζ·J·ω, ki = kp·ω/4, the acceleration feed-forward `J`, the disturbance observer's
//! nominal inertia `J`). A heavier tool raises `J` (a 0.3 kg cutting head instead of 0.04 kg
//! takes the paper machine's from 7.4e-3 to 13.2e-3 kg·m²); with the lighter machine's gains the
//! observer, whose nominal inertia is then half the axis', and the PID oscillate together against
//! the torque limit. The rule:
//!
//! * **identified dynamics in force** (the image's dynamics block): every axis' gains are the
//!   settings' scaled by `J / J₀` ([`scaled_for_inertia`]), `J` the axis' inertia by the
//!   identified model ([`axis_inertia_kg_m2`]) and `J₀` the inertia the settings were designed
//!   for (their `inertia_ff_kg_m2`): the same bandwidth and damping on the machine as it is;
//! * **no identified dynamics** (a commissioning image): the settings' gains with the observer
//!   off ([`without_observer`]). Its nominal inertia would be a guess, and a guess far under the
//!   axis' destabilises the loop, while the PID alone stays stable for every inertia the machine
//!   record accepts (it only lags more). This is the state a machine is identified in.
//!
//! Cost: [`axis_inertia_kg_m2`] solves the IK and two inverse dynamics at up to
//! [`INERTIA_POINTS`] tool points (`cargo qemu-bench`'s `gain_design` line gives the figure),
//! once per calibration engaged, never per sample; the scaling is ten multiplications.
//!
//! ```
//! use kinematics_core::gain_design::{scaled_for_inertia, without_observer};
//! use kinematics_core::ServoConfig;
//! let base = ServoConfig::default().axes[0];
//! let heavy = scaled_for_inertia(&base, 2.0 * base.inertia_ff_kg_m2).unwrap();
//! assert_eq!(heavy.kp_nm_per_rad, 2.0 * base.kp_nm_per_rad);
//! assert_eq!(heavy.observer_inertia_kg_m2, 2.0 * base.observer_inertia_kg_m2);
//! assert_eq!(heavy.torque_limit_nm, base.torque_limit_nm);
//! assert_eq!(without_observer(&base).observer_bandwidth_rad_s, 0.0);
//! ```
use crate::dynamics::FiveBarDynamics;
use crate::model::FiveBar;
use crate::pid::AxisGains;
use crate::real::Real;
use crate::servo::ServoConfig;
use crate::workspace::ConvexWorkspace;

/// Most tool points [`axis_inertia_kg_m2`] evaluates: the workspace's centroid and the
/// midpoints towards four of its vertices.
pub const INERTIA_POINTS: usize = 5;

/// The largest factor, either way, [`scaled_for_inertia`] scales gains by: the machine record's
/// largest dynamics factor (an image beyond it is refused before it is engaged).
pub const MAX_INERTIA_RATIO: f32 = 20.0;

/// The tool points an axis' inertia is averaged over: the centroid of `region`'s vertices and
/// the midpoints between it and four vertices spread around the polygon (all inside: the
/// region is convex). The array and how many are used.
pub fn inertia_points<T: Real>(region: &ConvexWorkspace<T>) -> ([[T; 2]; INERTIA_POINTS], usize) {
    let v = region.vertices_mm();
    let mut out = [[T::ZERO; 2]; INERTIA_POINTS];
    if v.is_empty() {
        return (out, 0);
    }
    let mut c = [T::ZERO; 2];
    for p in v {
        c = [c[0] + p[0], c[1] + p[1]];
    }
    let n = T::from_f64(v.len() as f64);
    c = [c[0] / n, c[1] / n];
    out[0] = c;
    let towards = (INERTIA_POINTS - 1).min(v.len());
    let half = T::from_f64(0.5);
    for (k, slot) in out[1..=towards].iter_mut().enumerate() {
        let p = v[k * v.len() / towards];
        *slot = [(c[0] + p[0]) * half, (c[1] + p[1]) * half];
    }
    (out, 1 + towards)
}

/// Each axis' inertia by `dynamics` (kg·m²): the diagonal of its inertia matrix averaged over
/// [`inertia_points`] of `region` that `model` reaches `min_transmission` from a singularity.
/// `None` when no point gives a positive finite diagonal (nothing to design for).
pub fn axis_inertia_kg_m2<T: Real>(
    dynamics: &FiveBarDynamics<T>,
    model: &FiveBar<T>,
    region: &ConvexWorkspace<T>,
    min_transmission: T,
) -> Option<[T; 2]> {
    let (points, n) = inertia_points(region);
    let (mut sum, mut used) = ([T::ZERO; 2], 0usize);
    for p in &points[..n] {
        let Ok(pose) = model.inverse_pose(*p, min_transmission) else {
            continue;
        };
        let Ok(m) = dynamics.inertia_diagonal(&pose) else {
            continue;
        };
        if m[0] > T::ZERO && m[1] > T::ZERO && m[0].is_finite() && m[1].is_finite() {
            sum = [sum[0] + m[0], sum[1] + m[1]];
            used += 1;
        }
    }
    if used == 0 {
        return None;
    }
    let k = T::from_f64(used as f64);
    Some([sum[0] / k, sum[1] / k])
}

/// `base`, designed for the inertia `base.inertia_ff_kg_m2`, scaled to an axis of inertia
/// `inertia_kg_m2`: kp, ki, kd, the acceleration feed-forward and the observer's nominal
/// inertia times `J / J₀` (the same bandwidths and damping), the limits, friction
/// feed-forward and observer bandwidth kept. `None` when there is no design inertia (`J₀` not
/// positive) or the ratio is not finite or beyond [`MAX_INERTIA_RATIO`] either way.
pub fn scaled_for_inertia(base: &AxisGains, inertia_kg_m2: f32) -> Option<AxisGains> {
    let r = inertia_kg_m2 / base.inertia_ff_kg_m2;
    if !(base.inertia_ff_kg_m2 > 0.0 && (1.0 / MAX_INERTIA_RATIO..=MAX_INERTIA_RATIO).contains(&r))
    {
        return None;
    }
    Some(AxisGains {
        kp_nm_per_rad: base.kp_nm_per_rad * r,
        ki_nm_per_rad_s: base.ki_nm_per_rad_s * r,
        kd_nm_s_per_rad: base.kd_nm_s_per_rad * r,
        inertia_ff_kg_m2: inertia_kg_m2,
        observer_inertia_kg_m2: base.observer_inertia_kg_m2 * r,
        ..*base
    })
}

/// `base` with the disturbance observer off (module doc: no identified inertia to trust).
pub fn without_observer(base: &AxisGains) -> AxisGains {
    AxisGains {
        observer_bandwidth_rad_s: 0.0,
        ..*base
    }
}

/// The servo settings the controller runs a calibration with (module doc): `settings` with
/// each axis' gains designed for `inertia_kg_m2` (the identified dynamics' axis inertias), or
/// with the observer off when there is none or an axis' ratio is out of range.
pub fn servo_config_for(settings: &ServoConfig, inertia_kg_m2: Option<[f32; 2]>) -> ServoConfig {
    let mut config = *settings;
    for (k, axis) in config.axes.iter_mut().enumerate() {
        *axis = inertia_kg_m2
            .and_then(|j| scaled_for_inertia(axis, j[k]))
            .unwrap_or_else(|| without_observer(axis));
    }
    config
}

/// [`servo_config_for`] with the inertias of `dynamics` (if any) over `region`:
/// the whole rule in one call.
pub fn servo_config_for_dynamics(
    settings: &ServoConfig,
    dynamics: Option<&FiveBarDynamics<f32>>,
    model: &FiveBar<f32>,
    region: &ConvexWorkspace<f32>,
) -> ServoConfig {
    let inertia =
        dynamics.and_then(|d| axis_inertia_kg_m2(d, model, region, settings.min_transmission));
    servo_config_for(settings, inertia)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn region() -> ConvexWorkspace<f32> {
        ConvexWorkspace::rectangle([162.132f32, 262.132], [-75.0, 75.0]).unwrap()
    }

    #[test]
    fn the_points_are_the_centroid_and_midpoints_inside_the_region() {
        let r = region();
        let (p, n) = inertia_points(&r);
        assert_eq!(n, INERTIA_POINTS);
        assert!(
            (p[0][0] - 212.132).abs() < 1e-3 && p[0][1].abs() < 1e-3,
            "{p:?}"
        );
        for q in &p[..n] {
            assert!(r.contains(*q, 1.0), "{q:?}");
        }
        let t = ConvexWorkspace::new(&[[0.0f32, 0.0], [80.0, 0.0], [0.0, 80.0]]).unwrap();
        assert_eq!(
            inertia_points(&t).1,
            4,
            "a triangle: its centroid and three midpoints"
        );
    }

    #[test]
    fn the_scaling_keeps_the_bandwidth_and_refuses_absurd_ratios() {
        let base = ServoConfig::default().axes[0];
        let half = scaled_for_inertia(&base, 0.5 * base.inertia_ff_kg_m2).unwrap();
        // ω² = kp / J and 2ζω = kd / J are the design's.
        let w2 = |g: &AxisGains| g.kp_nm_per_rad / g.inertia_ff_kg_m2;
        assert!((w2(&half) / w2(&base) - 1.0).abs() < 1e-6);
        assert_eq!(half.observer_bandwidth_rad_s, base.observer_bandwidth_rad_s);
        for j in [
            0.0,
            -1.0,
            f32::NAN,
            f32::INFINITY,
            100.0 * base.inertia_ff_kg_m2,
        ] {
            assert_eq!(scaled_for_inertia(&base, j), None, "{j}");
        }
        let none = AxisGains {
            inertia_ff_kg_m2: 0.0,
            ..base
        };
        assert_eq!(scaled_for_inertia(&none, 7e-3), None);
    }

    #[test]
    fn without_dynamics_the_observer_is_off_and_with_them_the_gains_follow_the_inertia() {
        let settings = ServoConfig::default();
        let quiet = servo_config_for(&settings, None);
        for (a, b) in quiet.axes.iter().zip(settings.axes) {
            assert_eq!(a.observer_bandwidth_rad_s, 0.0);
            assert_eq!(a.kp_nm_per_rad, b.kp_nm_per_rad);
        }
        let j0 = settings.axes[0].inertia_ff_kg_m2;
        let heavy = servo_config_for(&settings, Some([1.8 * j0, j0]));
        assert!((heavy.axes[0].kp_nm_per_rad / settings.axes[0].kp_nm_per_rad - 1.8).abs() < 1e-5);
        assert_eq!(heavy.axes[1], settings.axes[1]);
        assert!(heavy.validate().is_ok());
        // One axis out of range: that axis runs without the observer, the other as designed.
        let odd = servo_config_for(&settings, Some([f32::NAN, 1.8 * j0]));
        assert_eq!(odd.axes[0], without_observer(&settings.axes[0]));
        assert_eq!(odd.axes[1], heavy.axes[0]);
    }

    #[test]
    fn the_paper_machines_inertia_is_its_design_inertia() {
        let model = crate::paper::nominal::<f32>();
        let d = crate::paper::nominal_dynamics::<f32>();
        let j = axis_inertia_kg_m2(&d, &model, &region(), 0.05).unwrap();
        for v in j {
            assert!((v / 7.4e-3 - 1.0).abs() < 0.05, "{j:?}");
        }
        let far = ConvexWorkspace::rectangle([900.0f32, 950.0], [900.0, 950.0]).unwrap();
        assert_eq!(axis_inertia_kg_m2(&d, &model, &far, 0.05), None);
    }
}
