// The same-core cases: a fixed computation over `kinematics-core` whose every result must be
// bit-identical on the MCU (firmware/src/bin/golden.rs, under QEMU) and on the host
// (tests/tests/same_core_on_mcu.rs). Both `include!` this file, so there is one definition.
//
// no_std, no heap: only `kinematics_core` and core. Each result is emitted as a `u32`: an f32's
// bits, or `ERROR | code` for a refused input, so that errors must agree too. Transcendentals
// go through `Real` explicitly: on the host, `f32::sin_cos` would be std's, not the core's.

use kinematics_core::grid::{append_backlash, encode, CorrectionGrid, GridGeometry, BACKLASH_LEN};
use kinematics_core::path::Circle;
use kinematics_core::trajectory::{PathMotion, TaskLimits};
use kinematics_core::servo::{ServoOutput, StepError};
use kinematics_core::{
    Backlash, Calibration, FiveBar, FiveBarDynamics, IkMargin, MotionSetpoint, Real, Servo, ServoConfig, ValidCalibration, WorkingMode,
};

/// Marks an emitted error code (no f32 result has these bits: a NaN payload the core never makes).
pub const ERROR: u32 = 0x7fc0_de00;

/// Number of targets.
pub const TARGETS: usize = 96;

/// A calibrated-looking machine: unequal links, both bases offset, encoder offsets.
pub fn model() -> FiveBar<f32> {
    FiveBar {
        a_mm: 149.868,
        b_mm: 150.21,
        c_mm: 149.74,
        d_mm: 150.12,
        base_a0_mm: [-0.61, 0.27],
        base_b0_mm: [0.35, -0.8],
        encoder_offset_rad: [0.004, -0.007],
        mode: WorkingMode::PAPER,
    }
}

/// Target `k`: a quasi-random spread over the paper workspace, then a few hostile ones.
pub fn target_mm(k: usize) -> [f32; 2] {
    match k {
        90 => [f32::NAN, 0.0],
        91 => [400.0, 0.0],
        92 => [0.0, 0.0],
        93 => [f32::INFINITY, 1.0],
        94 => [299.0, 0.0],
        95 => [162.132, -75.0],
        _ => {
            let u = (k as f32 * 0.618_034) % 1.0;
            let v = (k as f32 * 0.754_877_7) % 1.0;
            [162.132 + 100.0 * u, -75.0 + 150.0 * v]
        }
    }
}

fn emit_result(emit: &mut impl FnMut(u32), r: Result<[f32; 2], u32>) {
    match r {
        Ok(v) => {
            emit(v[0].to_bits());
            emit(v[1].to_bits());
        }
        Err(code) => emit(ERROR | code),
    }
}

fn code<E: core::fmt::Debug>(e: E) -> u32 {
    // A short, stable code from the error's Debug text (same derive on both targets).
    let mut h: u32 = 0;
    let mut w = HashWriter(&mut h);
    let _ = core::fmt::write(&mut w, format_args!("{e:?}"));
    h & 0xff
}

/// Whether two steps gave the same result, bit for bit (the checked-once path against the
/// per-call one: the model's checks run outside the sample, its arithmetic is the same).
fn same_step(a: &Result<ServoOutput, StepError>, b: &Result<ServoOutput, StepError>) -> bool {
    match (a, b) {
        (Ok(a), Ok(b)) => {
            let bits = |o: &ServoOutput| [o.torque_nm, o.reference_rad, o.following_error_rad].map(|v| v.map(f32::to_bits));
            bits(a) == bits(b)
        }
        (Err(a), Err(b)) => a == b,
        _ => false,
    }
}

/// Marks a disagreement of the checked-once path with the per-call one (outside the `ERROR`
/// codes; `tests/tests/same_core_on_mcu.rs` fails on it).
pub const VALID_PATH_DIFFERS: u32 = 0x7fc0_df01;

struct HashWriter<'a>(&'a mut u32);

impl core::fmt::Write for HashWriter<'_> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for b in s.bytes() {
            *self.0 = self.0.wrapping_mul(31).wrapping_add(b as u32);
        }
        Ok(())
    }
}

/// Runs every case, emitting the results in a fixed order.
pub fn run(emit: &mut impl FnMut(u32)) {
    let m = model();
    // 1. IK, FK of the IK, the Jacobian.
    for k in 0..TARGETS {
        let p = target_mm(k);
        let pose = m.inverse_pose(p, 0.05);
        emit_result(emit, pose.map(|q| q.theta_rad).map_err(code));
        if let Ok(q) = pose {
            emit_result(emit, m.forward(q.theta_rad, 0.0).map_err(code));
            match q.jacobian() {
                Ok(j) => j.iter().flatten().for_each(|v| emit(v.to_bits())),
                Err(e) => emit(ERROR | code(e)),
            }
        }
    }
    // 2. A correction grid built in place, and lookups through it.
    let g = GridGeometry { nx: 6, ny: 7, x0_mm: 162.132, y0_mm: -75.0, step_x_mm: 20.0, step_y_mm: 25.0 };
    let mut nodes = [[0.0f32; 2]; 42];
    for (n, node) in nodes.iter_mut().enumerate() {
        let (s, c) = Real::sin_cos(n as f32 * 0.37);
        *node = [3e-4 * s, -2e-4 * c];
    }
    let mut image = [0u8; 72 + 8 * 42 + 4];
    if encode(&mut image, &g, &m, &nodes).is_err() {
        emit(ERROR | 0xee);
        return;
    }
    let Ok(grid) = CorrectionGrid::parse(&image) else {
        emit(ERROR | 0xef);
        return;
    };
    let cal = Calibration::from_grid(grid);
    let valid = ValidCalibration::from_grid(grid);
    for k in 0..TARGETS {
        let command = cal.command_rad(target_mm(k), 0.05);
        if command.map(|t| t.map(f32::to_bits)) != valid.command_rad(target_mm(k), IkMargin::new(0.05)).map(|t| t.map(f32::to_bits)) {
            emit(VALID_PATH_DIFFERS);
        }
        emit_result(emit, command.map_err(code));
    }
    // 3. The servo closed around a two-inertia plant (the default gains' 7.4e-3 kg·m²) for 400
    //    samples of a 10 mm circle.
    let Ok(mut servo) = Servo::new(ServoConfig::default()) else {
        emit(ERROR | 0xf1);
        return;
    };
    // The same servo through the checked-once path, stepped alongside: the same results.
    let mut servo_valid = servo.clone();
    let centre = [202.132f32, 0.0];
    let Ok(mut angle) = cal.command_rad([centre[0] + 10.0, centre[1]], 0.05) else {
        emit(ERROR | 0xf0);
        return;
    };
    let mut velocity = [0.0f32; 2];
    if let Err(e) = servo.engage(&cal, angle).and(servo_valid.engage(&cal, angle)) {
        emit(ERROR | code(e));
        return;
    }
    for n in 0..400 {
        let t = n as f32 * 5e-4;
        let phase = core::f32::consts::TAU * t * t; // angular speed ramps up from zero
        let (s, c) = Real::sin_cos(phase);
        let setpoint = [centre[0] + 10.0 * c, centre[1] + 10.0 * s];
        let stepped = servo.step(&cal, setpoint, angle);
        if !same_step(&stepped, &servo_valid.step(&valid, setpoint, angle)) {
            emit(VALID_PATH_DIFFERS);
        }
        match stepped {
            Ok(out) => {
                emit(out.torque_nm[0].to_bits());
                emit(out.torque_nm[1].to_bits());
                for k in 0..2 {
                    velocity[k] += out.torque_nm[k] / 7.4e-3 * 5e-4;
                    angle[k] += velocity[k] * 5e-4;
                }
            }
            Err(e) => {
                emit(ERROR | code(e));
                return;
            }
        }
    }
    // 4. A 5 g circle's time law (planning and sampling: sqrt, cbrt, sin_cos), the
    //    joint motion and inverse dynamics at each sample, and the motion step with them fed
    //    forward around the same plant.
    let limits = TaskLimits { speed_mm_s: 1500.0f32, accel_mm_s2: 49_033.25, jerk_mm_s3: 5.0e6 };
    let circle = Circle { centre_mm: [212.132f32, 0.0], radius_mm: 30.0, start_rad: 0.0, turns: 1.0 };
    let contour = match PathMotion::plan(circle, &limits, 64) {
        Ok(c) => c,
        Err(e) => {
            emit(ERROR | code(e));
            return;
        }
    };
    emit(contour.duration_s().to_bits());
    let dynamics = FiveBarDynamics {
        motor_inertia_kg_m2: [3.9e-3f32, 3.8e-3],
        tool_mass_kg: 0.165,
        distal_inertia_kg_m2: [-2.4e-4, -2.5e-4],
        viscous_nm_s_per_rad: [0.02, 0.02],
        coulomb_nm: [0.05, 0.04],
        coulomb_speed_rad_s: 0.01,
    };
    let Ok(mut servo) = Servo::new(ServoConfig::default()) else {
        emit(ERROR | 0xf2);
        return;
    };
    let _ = servo.set_dynamics(Some(dynamics));
    let mut servo_valid = servo.clone();
    let Ok(mut angle) = cal.command_rad(contour.at(0.0).position_mm, 0.05) else {
        emit(ERROR | 0xf3);
        return;
    };
    let mut velocity = [0.0f32; 2];
    if let Err(e) = servo.engage(&cal, angle).and(servo_valid.engage(&cal, angle)) {
        emit(ERROR | code(e));
        return;
    }
    for n in 0..200 {
        let s = contour.at(n as f32 * 5e-4);
        s.position_mm.iter().chain(&s.velocity_mm_s).chain(&s.acceleration_mm_s2).chain(&s.jerk_mm_s3).for_each(|v| emit(v.to_bits()));
        match m.inverse_motion(s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, 0.05).and_then(|j| dynamics.torque_nm(&j)) {
            Ok(t) => t.iter().for_each(|v| emit(v.to_bits())),
            Err(e) => emit(ERROR | code(e)),
        }
        // Every other sample with the next setpoint, the others predicting it.
        let next = contour.at((n + 1) as f32 * 5e-4);
        let stepped = servo.step_motion(&cal, &s, (n % 2 == 0).then_some(&next), angle);
        if !same_step(&stepped, &servo_valid.step_motion(&valid, &s, (n % 2 == 0).then_some(&next), angle)) {
            emit(VALID_PATH_DIFFERS);
        }
        match stepped {
            Ok(out) => {
                emit(out.torque_nm[0].to_bits());
                emit(out.torque_nm[1].to_bits());
                for k in 0..2 {
                    velocity[k] += out.torque_nm[k] / 7.4e-3 * 5e-4;
                    angle[k] += velocity[k] * 5e-4;
                }
            }
            Err(e) => {
                emit(ERROR | code(e));
                return;
            }
        }
    }
    // 5. The same grid with a backlash block (20 and 35 µrad), the servo (plain and
    //    motion step) out and back along a line, so that both joints reverse: the reference
    //    with its play-operator correction and the torques, bit for bit.
    let mut with_backlash = [0u8; 72 + 8 * 42 + 4 + BACKLASH_LEN];
    with_backlash[..image.len()].copy_from_slice(&image);
    let Ok(backlash) = Backlash::new([20e-6f32, 35e-6]) else {
        emit(ERROR | 0xf4);
        return;
    };
    let Ok(end) = append_backlash(&mut with_backlash, image.len(), image.len(), &backlash) else {
        emit(ERROR | 0xf5);
        return;
    };
    let Ok(grid) = CorrectionGrid::parse(&with_backlash[..end]) else {
        emit(ERROR | 0xf6);
        return;
    };
    let (cal, valid) = (Calibration::from_grid(grid), ValidCalibration::from_grid(grid));
    let line = |n: usize| {
        // 3 mm out in 0.2 s and back (smoothstep), 10 samples at rest at each end.
        let u = (n as f32 / 400.0).min(1.0);
        let w = if n < 410 { u } else { 1.0 - ((n - 410) as f32 / 400.0).min(1.0) };
        let x = 3.0 * w * w * (3.0 - 2.0 * w);
        [195.0 + x, 5.0 + 0.5 * x]
    };
    for motion in [false, true] {
        let Ok(mut servo) = Servo::new(ServoConfig::default()) else {
            emit(ERROR | 0xf7);
            return;
        };
        let mut servo_valid = servo.clone();
        let Ok(mut angle) = cal.command_rad(line(0), 0.05) else {
            emit(ERROR | 0xf8);
            return;
        };
        let mut velocity = [0.0f32; 2];
        if let Err(e) = servo.engage(&cal, angle).and(servo_valid.engage(&cal, angle)) {
            emit(ERROR | code(e));
            return;
        }
        for n in 0..820 {
            let stepped = if motion {
                let at = |n: usize| MotionSetpoint { position_mm: line(n), velocity_mm_s: [0.0; 2], acceleration_mm_s2: [0.0; 2], jerk_mm_s3: [0.0; 2] };
                let (s, next) = (at(n), at(n + 1));
                let stepped = servo.step_motion(&cal, &s, Some(&next), angle);
                if !same_step(&stepped, &servo_valid.step_motion(&valid, &s, Some(&next), angle)) {
                    emit(VALID_PATH_DIFFERS);
                }
                stepped
            } else {
                let stepped = servo.step(&cal, line(n), angle);
                if !same_step(&stepped, &servo_valid.step(&valid, line(n), angle)) {
                    emit(VALID_PATH_DIFFERS);
                }
                stepped
            };
            match stepped {
                Ok(out) => {
                    out.reference_rad.iter().chain(&out.torque_nm).for_each(|v| emit(v.to_bits()));
                    for k in 0..2 {
                        velocity[k] += out.torque_nm[k] / 7.4e-3 * 5e-4;
                        angle[k] += velocity[k] * 5e-4;
                    }
                }
                Err(e) => {
                    emit(ERROR | code(e));
                    return;
                }
            }
        }
    }
}
