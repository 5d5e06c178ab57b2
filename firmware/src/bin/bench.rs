//! Instruction / cycle counts of the hot path, one line per figure:
//! `BENCH <name> <instructions per call>` (QEMU; `firmware/qemu/bench.sh` appends the
//! estimated Cortex-M4 cycles) or `BENCH <name> <cycles per call>` (STM32G474, DWT).
//!
//! * `ik_f32`: `FiveBar::<f32>::inverse` (closed-form IK, singularity checks, the model's
//!   links and the margin's floor checked on every call);
//! * `ik_f32_valid`: `ValidFiveBar::<f32>::inverse`, the same IK with the model and margin
//!   checked once (`IkMargin`): the servo's IK;
//! * `fk_f32`: `FiveBar::<f32>::forward`;
//! * `grid_lookup`: `CorrectionGrid::correction_rad` on the image in the calibration region;
//! * `servo_step`: `Servo::step` with a `ValidCalibration`, the whole sample (jump checks, IK, correction, two
//!   PIDs) with a `ValidCalibration`, the firmware's path (and `servo_step_checking`:
//!   `Servo::step` with a plain `Calibration`, whose model every IK checks);
//! * `jerk_profile_at`, `trajectory_line_at`, `trajectory_circle_at`: one sample of a 5 g
//!   trajectory (the 1-D profile alone, a straight move, a circle), exact derivatives included;
//! * `inverse_motion_f32`: joint angles, velocities and accelerations for a tool motion;
//! * `inverse_dynamics_f32`: the hidden robot's inverse dynamics from that joint motion;
//! * `servo_step_backlash`: `servo_step` with a backlash block appended to the image (20 µrad
//!   per drive): the reference's backlash compensation (`kinematics_core::backlash`) included;
//! * `servo_step_motion`: one sample of 5 g moves back and forth across the workspace: the
//!   trajectory evaluated (exact derivatives) and `Servo::step_motion` with the identified
//!   dynamics fed forward (`Servo::step_motion` with a `ValidCalibration`; and `servo_step_motion_uncorrected`,
//!   without grid, and `servo_step_motion_backlash`, with the backlash block);
//! * `judge_image`: `kinematics_core::machine::judge_image`, a calibration image (the region's:
//!   651 nodes, workspace and dynamics blocks) judged against the built-in machine record
//!   (same machine, then plausible), and `image_commit_check`: what an upload's commit judges
//!   (`controller::calibration::validate_image`: the parse, that judgement, the servo's
//!   slope-change limit). At boot and in the link task, never in a servo sample;
//! * `gain_design`: `kinematics_core::gain_design::servo_config_for_dynamics`, the servo
//!   gains for that image's dynamics (the axis inertias at five workspace points): once per
//!   calibration put in force, at boot or in the sample that switches to an upload;
//! * `sixbar_solve`: the six-bar's numerical equilibrium solve (host-sim's plant, ported to
//!   f32 in `bench/sixbar.rs`), warm-started along the servo's 2 kHz path: what controlling
//!   the real mechanism without the hidden robot would cost per sample (and
//!   `sixbar_solve_scattered`: from one lattice point to another, as between measurements);
//!
//! and, to show what bounds them: `atan2_f32` and `sin_cos_f32` (the core's, one per arm of
//! the IK and FK), libm's `atan2f` and `sincosf` they replace, and `servo_step_uncorrected`
//! (the same step without grid).
//!
//! Method: each figure is `(counts(N calls) - counts(N empty iterations)) / N`, the inputs
//! cycling through points spread over the workspace and passed through `black_box`, so that
//! loop overhead is removed and nothing is folded at compile time.
//!
//! * QEMU (`cargo qemu-bench`, `-icount shift=0`): the counter is SysTick on the core clock;
//!   how many instructions one SysTick count is gets *measured* first with a loop of known
//!   length (`subs`/`bne`, two instructions per iteration), not assumed. QEMU counts
//!   instructions, not cycles; the cycle estimate comes from the plugin
//!   `qemu/plugin/m4cycles.c`, which sees both loops of every figure as windows between the
//!   markers of [`window_start`] and [`window_end`].
//! * STM32G474: the counter is DWT CYCCNT and the figures are core cycles
//!   (printed over defmt-RTT as `BENCH <name> <cycles per call>`).
#![no_std]
#![no_main]

#[cfg(feature = "board-g474")]
use defmt_rtt as _;

use core::fmt::Write;
use core::hint::black_box;

use cortex_m_rt::entry;
use kinematics_core::atan2::atan2_f32;
use kinematics_core::grid::{append_backlash, BACKLASH_LEN};
use kinematics_core::path::Circle;
use kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
use kinematics_core::servo::{ServoOutput, StepError};
use kinematics_core::sin_cos::sin_cos_f32;
use kinematics_core::Backlash;
use kinematics_core::{
    Calibration, CorrectionGrid, FiveBar, FiveBarDynamics, IkMargin, MotionSetpoint, PathMotion,
    Servo, ServoConfig, TaskLimits, ValidCalibration, ValidFiveBar,
};

use controller::calibration::{validate_image, Judged};
use controller::settings::Settings;
use firmware::board::{self, CycleCounter};
use firmware::calibration;
use kinematics_core::gain_design::servo_config_for_dynamics;
use kinematics_core::machine::{judge_image, MachineRecord};

// The port lives next to this file (a crate root resolves `mod` from its own directory).
#[path = "bench/sixbar.rs"]
mod sixbar;

/// Calls per figure.
const N: usize = 2_000;
/// Distinct inputs cycled through.
const POINTS: usize = 64;
/// Calls of the image judgements (some 3e5 instructions each).
const JUDGE_CALLS: usize = 8;

/// Prints one result line.
fn report(name: &str, per_call: f32) {
    let mut line: heapless::String<96> = heapless::String::new();
    let _ = write!(line, "BENCH {} {:.1}", name, per_call);
    board::console(&line);
    defmt::println!("{=str}", line.as_str());
}

/// Announces the calls per figure of the `BENCH` lines that follow (`firmware/qemu/bench.sh`
/// divides the plugin's windows by it).
fn calls_per_figure(calls: usize) {
    let mut line: heapless::String<96> = heapless::String::new();
    let _ = write!(line, "# calls per figure: {}", calls);
    board::console(&line);
}

/// Counts of a loop of `2 · iterations` instructions (`subs` + `bne` per iteration).
fn known_loop(counter: &CycleCounter, iterations: u32) -> u32 {
    let start = counter.now();
    // SAFETY: a register-only countdown loop.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {n}, {n}, #1",
            "bne 2b",
            n = inout(reg) iterations => _,
            options(nomem, nostack),
        );
    }
    counter.since(start)
}

/// Opens a measurement window for the QEMU cycle-estimating plugin
/// (`firmware/qemu/plugin/m4cycles.c`): `mov r10, r10`, a no-op (one cycle on hardware) that
/// the compiler never emits.
#[inline(always)]
fn window_start() {
    // SAFETY: moves a register onto itself; no memory, stack or flags. Not `nomem`, so that the
    // compiler keeps memory accesses on their side of the marker.
    unsafe { core::arch::asm!("mov r10, r10", options(nostack, preserves_flags)) }
}

/// Closes a measurement window (`mov r11, r11`, see [`window_start`]).
#[inline(always)]
fn window_end() {
    // SAFETY: as in `window_start`.
    unsafe { core::arch::asm!("mov r11, r11", options(nostack, preserves_flags)) }
}

/// Measured counts of `body(i)` over `N` calls, minus the same loop with an empty body.
///
/// Each loop is also a plugin window (empty loop first, then the body), so that
/// `firmware/qemu/bench.sh` pairs window `2k` and `2k + 1` with the `k`-th `BENCH` line.
fn measure(counter: &CycleCounter, body: impl FnMut(usize)) -> u32 {
    measure_calls(counter, N, body)
}

/// [`measure`] over `calls` calls (for bodies whose `N` calls would not fit the counter's
/// range: under QEMU 2^24 ticks, some 6.7e8 instructions).
fn measure_calls(counter: &CycleCounter, calls: usize, mut body: impl FnMut(usize)) -> u32 {
    window_start();
    let start = counter.now();
    for i in 0..calls {
        black_box(i);
    }
    let empty = counter.since(start);
    window_end();
    window_start();
    let start = counter.now();
    for i in 0..calls {
        body(black_box(i));
    }
    let total = counter.since(start);
    window_end();
    total.saturating_sub(empty)
}

/// One `Servo::step` with a `ValidCalibration` as the firmware's timer interrupt makes it (the model checked
/// once, when the calibration was loaded): a call of its own, so that nothing of the servo
/// (its settings, its history) stays in registers from one call to the next, as it could if
/// the step were inlined into the measuring loop.
#[inline(never)]
fn step_once(
    servo: &mut Servo,
    cal: &ValidCalibration<'_>,
    setpoint_mm: [f32; 2],
    encoder_rad: [f32; 2],
) -> Result<ServoOutput, StepError> {
    servo.step(cal, setpoint_mm, encoder_rad)
}

/// One `Servo::step` with a plain `Calibration` (its model checked by every IK), a call of its
/// own (see [`step_once`]): what the check costs.
#[inline(never)]
fn step_once_checking(
    servo: &mut Servo,
    cal: &Calibration<'_>,
    setpoint_mm: [f32; 2],
    encoder_rad: [f32; 2],
) -> Result<ServoOutput, StepError> {
    servo.step(cal, setpoint_mm, encoder_rad)
}

/// One `Servo::step_motion` with a `ValidCalibration`, a call of its own (see [`step_once`]).
#[inline(never)]
fn step_motion_once(
    servo: &mut Servo,
    cal: &ValidCalibration<'_>,
    setpoint: &MotionSetpoint<f32>,
    next: &MotionSetpoint<f32>,
    encoder_rad: [f32; 2],
) -> Result<ServoOutput, StepError> {
    servo.step_motion(cal, setpoint, Some(next), encoder_rad)
}

/// Fails the run if a step of benchmark `name` faulted (the first fault, at its call).
fn exit_on_fault(name: &str, fault: Option<(usize, StepError)>) {
    if let Some((i, f)) = fault {
        let mut line: heapless::String<128> = heapless::String::new();
        let _ = write!(
            line,
            "FAIL {} faulted during the benchmark at call {}: {}",
            name, i, f
        );
        board::console(&line);
        board::exit(false);
    }
}

/// Reports the counts of `step` along `setpoints` (the encoders following the reference
/// exactly), engaged at the first setpoint with `cal`; fails the run if a step faults.
fn bench_step(
    counter: &CycleCounter,
    per_count: f32,
    name: &str,
    cal: &Calibration<'_>,
    setpoints: &[[f32; 2]; N],
    mut step: impl FnMut(&mut Servo, [f32; 2], [f32; 2]) -> Result<ServoOutput, StepError>,
) {
    let Ok(mut servo) = Servo::new(ServoConfig::default()) else {
        board::exit(false)
    };
    let Ok(mut encoder) = cal.command_rad(setpoints[0], 0.05) else {
        board::exit(false)
    };
    if servo.engage(cal, encoder).is_err() {
        board::console("FAIL servo did not engage");
        board::exit(false);
    }
    let mut fault = None;
    let counts = measure(counter, |i| {
        match step(&mut servo, black_box(setpoints[i]), black_box(encoder)) {
            Ok(out) => encoder = out.reference_rad,
            Err(f) => fault = fault.or(Some((i, f))),
        }
    });
    exit_on_fault(name, fault);
    report(name, counts as f32 * per_count / N as f32);
}

#[entry]
fn main() -> ! {
    // The clock the app runs at, so that the cycles are the servo's: STM32G474 170 MHz from the
    // PLL, range-1 boost, 4 flash wait states, prefetch and I/D caches (the board's own clock
    // plan; without it the chip runs on HSI16 at 16 MHz with 0 wait states). QEMU: nothing.
    board::bench_init();
    let Some(core) = cortex_m::Peripherals::take() else {
        board::exit(false)
    };
    let counter = CycleCounter::new(core);

    // What one count is worth, in instructions (QEMU) or cycles (hardware: 1.0).
    let (short, long) = (known_loop(&counter, 100_000), known_loop(&counter, 300_000));
    let per_count = if long > short {
        400_000.0 / (long - short) as f32
    } else {
        0.0
    };
    let mut line: heapless::String<96> = heapless::String::new();
    let _ = write!(
        line,
        "# {} per counter tick: {:.3} (measured with a known loop)",
        board::COUNT_UNIT,
        per_count
    );
    board::console(&line);
    calls_per_figure(N);
    if per_count <= 0.0 {
        board::console("FAIL counter does not run");
        board::exit(false);
    }

    let model = FiveBar::<f32>::paper_nominal();
    let grid = match CorrectionGrid::parse(calibration::region()) {
        Ok(g) => g,
        Err(_) => {
            board::console("FAIL no valid calibration image to benchmark the grid lookup");
            board::exit(false);
        }
    };
    let cal = ValidCalibration::from_grid(grid);

    // Points on a 8x8 lattice over the workspace, and their joint angles.
    let mut points = [[0.0f32; 2]; POINTS];
    let mut thetas = [[0.0f32; 2]; POINTS];
    for (k, p) in points.iter_mut().enumerate() {
        *p = [170.0 + 12.0 * (k % 8) as f32, -65.0 + 18.0 * (k / 8) as f32];
        thetas[k] = match model.inverse(*p, 0.05) {
            Ok(t) => t,
            Err(_) => {
                board::console("FAIL benchmark point out of reach");
                board::exit(false);
            }
        };
    }

    let ik = measure(&counter, |i| {
        let _ = black_box(model.inverse(black_box(points[i % POINTS]), 0.05));
    });
    report("ik_f32", ik as f32 * per_count / N as f32);

    let Ok(valid) = ValidFiveBar::new(model) else {
        board::exit(false)
    };
    let margin = IkMargin::new(0.05);
    let ik = measure(&counter, |i| {
        let _ = black_box(valid.inverse(black_box(points[i % POINTS]), margin));
    });
    report("ik_f32_valid", ik as f32 * per_count / N as f32);

    let fk = measure(&counter, |i| {
        let _ = black_box(model.forward(black_box(thetas[i % POINTS]), 0.05));
    });
    report("fk_f32", fk as f32 * per_count / N as f32);

    let atan2 = measure(&counter, |i| {
        let p = black_box(points[i % POINTS]);
        black_box(atan2_f32(p[1], p[0]));
    });
    report("atan2_f32", atan2 as f32 * per_count / N as f32);

    let atan2 = measure(&counter, |i| {
        let p = black_box(points[i % POINTS]);
        black_box(libm::atan2f(p[1], p[0]));
    });
    report("atan2f", atan2 as f32 * per_count / N as f32);

    let sin_cos = measure(&counter, |i| {
        black_box(sin_cos_f32(black_box(thetas[i % POINTS][0])));
    });
    report("sin_cos_f32", sin_cos as f32 * per_count / N as f32);

    let sin_cos = measure(&counter, |i| {
        black_box(libm::sincosf(black_box(thetas[i % POINTS][0])));
    });
    report("sincosf", sin_cos as f32 * per_count / N as f32);

    let lookup = measure(&counter, |i| {
        let _ = black_box(grid.correction_rad(black_box(points[i % POINTS])));
    });
    report("grid_lookup", lookup as f32 * per_count / N as f32);

    // The judgement of a calibration image (at boot, and in the link task at an upload's
    // commit; never in a servo sample): the machine's (`judge_image`: same machine, then
    // plausible) and the commit's whole check (parse, that judgement, the servo's slope-change
    // limit), on the image in the region (651 nodes, workspace and dynamics blocks) against
    // the built-in machine.
    calls_per_figure(JUDGE_CALLS);
    let machine = MachineRecord::paper();
    if judge_image(&grid, &machine).is_err() {
        board::console("FAIL the calibration image is refused by judge_image");
        board::exit(false);
    }
    let judge = measure_calls(&counter, JUDGE_CALLS, |_| {
        let _ = black_box(judge_image(black_box(&grid), &machine));
    });
    report("judge_image", judge as f32 * per_count / JUDGE_CALLS as f32);
    let check = Settings::default().image_check();
    let image = calibration::region();
    if validate_image(image, &check, Judged::AtCommit).is_err() {
        board::console("FAIL the calibration image is refused at a commit");
        board::exit(false);
    }
    let commit = measure_calls(&counter, JUDGE_CALLS, |_| {
        let _ = black_box(validate_image(black_box(image), &check, Judged::AtCommit).is_ok());
    });
    report(
        "image_commit_check",
        commit as f32 * per_count / JUDGE_CALLS as f32,
    );
    // The servo gains for the image's dynamics (`kinematics_core::gain_design`), computed once
    // when a calibration becomes the one in force (at boot, or in the servo sample that
    // switches to a committed upload, at rest).
    let settings = Settings::default();
    let gains = measure_calls(&counter, JUDGE_CALLS, |_| {
        black_box(servo_config_for_dynamics(
            &settings.servo,
            black_box(grid.dynamics()),
            grid.model(),
            &machine.workspace.region,
        ));
    });
    report("gain_design", gains as f32 * per_count / JUDGE_CALLS as f32);
    calls_per_figure(N);

    // Trajectory evaluation and dynamics: a 5 g move across the workspace and a
    // 40 mm circle at 5 g, sampled at instants spread over their durations.
    let limits = TaskLimits {
        speed_mm_s: 1500.0,
        accel_mm_s2: 5.0 * STANDARD_GRAVITY_MM_S2,
        jerk_mm_s3: 5.0e6,
    };
    let Ok(line) = PathMotion::line([170.0, -65.0], [255.0, 68.0], &limits) else {
        board::exit(false)
    };
    let circle = Circle {
        centre_mm: [212.132, 0.0],
        radius_mm: 40.0,
        start_rad: 0.0,
        turns: 1.0,
    };
    let Ok(contour) = PathMotion::plan(circle, &limits, 200) else {
        board::exit(false)
    };
    let times =
        |d: f32| core::array::from_fn::<f32, POINTS, _>(|k| d * k as f32 / (POINTS - 1) as f32);
    let (line_t, circle_t) = (times(line.duration_s()), times(contour.duration_s()));
    let profile = *line.law();
    let at = measure(&counter, |i| {
        black_box(profile.at(black_box(line_t[i % POINTS])));
    });
    report("jerk_profile_at", at as f32 * per_count / N as f32);
    let at = measure(&counter, |i| {
        black_box(line.at(black_box(line_t[i % POINTS])));
    });
    report("trajectory_line_at", at as f32 * per_count / N as f32);
    let at = measure(&counter, |i| {
        black_box(contour.at(black_box(circle_t[i % POINTS])));
    });
    report("trajectory_circle_at", at as f32 * per_count / N as f32);
    let setpoints_5g: [MotionSetpoint<f32>; POINTS] = core::array::from_fn(|k| line.at(line_t[k]));
    let motion = measure(&counter, |i| {
        let s = black_box(&setpoints_5g[i % POINTS]);
        let _ = black_box(model.inverse_motion(
            s.position_mm,
            s.velocity_mm_s,
            s.acceleration_mm_s2,
            0.05,
        ));
    });
    report("inverse_motion_f32", motion as f32 * per_count / N as f32);
    let mut motions = [None; POINTS];
    for (m, s) in motions.iter_mut().zip(&setpoints_5g) {
        *m = model
            .inverse_motion(s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, 0.05)
            .ok();
    }
    let Some(motions) = motions
        .into_iter()
        .collect::<Option<heapless::Vec<_, POINTS>>>()
    else {
        board::exit(false)
    };
    let dynamics = FiveBarDynamics {
        motor_inertia_kg_m2: [3.9e-3; 2],
        tool_mass_kg: 0.165,
        distal_inertia_kg_m2: [-2.4e-4; 2],
        viscous_nm_s_per_rad: [0.02; 2],
        coulomb_nm: [0.05; 2],
        coulomb_speed_rad_s: 0.01,
    };
    let torque = measure(&counter, |i| {
        let _ = black_box(dynamics.torque_nm(black_box(&motions[i % POINTS])));
    });
    report("inverse_dynamics_f32", torque as f32 * per_count / N as f32);

    // Servo step along a 20 mm circle, speeding up from rest at 2π rad/s² (the servo refuses
    // a start at speed as a jump), with the encoders following the reference exactly.
    let mut setpoints = [[0.0f32; 2]; N];
    for (k, s) in setpoints.iter_mut().enumerate() {
        let t_s = k as f32 * 5.0e-4;
        let phase = core::f32::consts::PI * t_s * t_s;
        let (sin, cos) = libm::sincosf(phase);
        *s = [212.132 + 20.0 * (cos - 1.0), 20.0 * sin];
    }
    let Ok(uncorrected) = ValidCalibration::new(Calibration { model, grid: None }) else {
        board::exit(false)
    };
    for (name, cal) in [
        ("servo_step", &cal),
        ("servo_step_uncorrected", &uncorrected),
    ] {
        bench_step(
            &counter,
            per_count,
            name,
            &cal.calibration(),
            &setpoints,
            |s, p, e| step_once(s, cal, p, e),
        );
    }
    // The same step with a backlash block in the image (20 µrad per drive, the
    // `paper` plant's): the servo's reference compensates it (`kinematics_core::backlash`).
    let mut image = [0u8; 8192];
    let (image_len, end) = (grid.geometry().image_len(), grid.len_bytes());
    let Some(flashed) = calibration::region().get(..end) else {
        board::exit(false)
    };
    if end + BACKLASH_LEN > image.len() {
        board::console("FAIL the calibration image is too large to append a backlash block to");
        board::exit(false);
    }
    image[..end].copy_from_slice(flashed);
    let Ok(backlash) = Backlash::new([20e-6, 20e-6]) else {
        board::exit(false)
    };
    let Ok(total) = append_backlash(&mut image, image_len, end, &backlash) else {
        board::exit(false)
    };
    let Ok(backlash_grid) = CorrectionGrid::parse(&image[..total]) else {
        board::exit(false)
    };
    let with_backlash = ValidCalibration::from_grid(backlash_grid);
    bench_step(
        &counter,
        per_count,
        "servo_step_backlash",
        &with_backlash.calibration(),
        &setpoints,
        |s, p, e| step_once(s, &with_backlash, p, e),
    );
    let checking = cal.calibration();
    bench_step(
        &counter,
        per_count,
        "servo_step_checking",
        &checking,
        &setpoints,
        |s, p, e| step_once_checking(s, &checking, p, e),
    );

    // The motion step: back and forth along the 5 g move without dwell (in motion but for an
    // instant at each end), the next setpoint evaluated from the trajectory at its sample's time
    // within the move (integer sample counts, as the firmware's setpoint source keeps them),
    // then `Servo::step_motion` with it as the look-ahead and the identified dynamics fed
    // forward.
    let Ok(back) = PathMotion::line([255.0, 68.0], [170.0, -65.0], &limits) else {
        board::exit(false)
    };
    let move_samples = libm::ceilf(line.duration_s() / 5.0e-4) as usize;
    let sample = |k: usize| {
        let n = k % (2 * move_samples);
        if n < move_samples {
            line.at(n as f32 * 5.0e-4)
        } else {
            back.at((n - move_samples) as f32 * 5.0e-4)
        }
    };
    for (name, cal) in [
        ("servo_step_motion", &cal),
        ("servo_step_motion_uncorrected", &uncorrected),
        ("servo_step_motion_backlash", &with_backlash),
    ] {
        let Ok(mut servo) = Servo::new(ServoConfig::default()) else {
            board::exit(false)
        };
        if servo.set_dynamics(Some(dynamics)).is_err() {
            board::exit(false);
        }
        let Ok(mut encoder) = cal.command_rad(sample(0).position_mm, IkMargin::new(0.05)) else {
            board::exit(false)
        };
        if servo.engage(&cal.calibration(), encoder).is_err() {
            board::console("FAIL servo did not engage");
            board::exit(false);
        }
        let mut fault = None;
        // One trajectory evaluation per step: the next setpoint (the current one is the last
        // step's next), as the setpoint task queues them.
        let mut current = sample(0);
        let step = measure(&counter, |i| {
            let next = sample(black_box(i) + 1);
            let stepped = step_motion_once(&mut servo, cal, &current, &next, black_box(encoder));
            current = next;
            match stepped {
                Ok(out) => encoder = out.reference_rad,
                Err(f) => fault = fault.or(Some((i, f))),
            }
        });
        exit_on_fault(name, fault);
        report(name, step as f32 * per_count / N as f32);
    }

    // The six-bar solve along the same path (link angles from the nominal IK, as host-sim's
    // plant benchmark does), warm-started from the previous sample like the plant.
    let mut links = [[0.0f32; 2]; N];
    for (k, l) in links.iter_mut().enumerate() {
        let Ok(t) = model.inverse(setpoints[k], 0.0) else {
            board::exit(false)
        };
        *l = t;
    }
    let mut plant = sixbar::SixBar::new(&sixbar::SixBarParams::paper());
    for (name, scattered) in [("sixbar_solve", false), ("sixbar_solve_scattered", true)] {
        let (mut iterations, mut failed) = (0u32, None);
        let solve = measure(&counter, |i| {
            let link = if scattered {
                thetas[(i * 7) % POINTS]
            } else {
                links[i]
            };
            match plant.solve(black_box(link)) {
                Ok(sol) => {
                    iterations += sol.iterations;
                    black_box(sol.tool_mm);
                }
                Err(e) => failed = failed.or(Some((i, e))),
            }
        });
        if let Some((i, e)) = failed {
            let mut line: heapless::String<128> = heapless::String::new();
            let _ = write!(line, "FAIL {} failed at call {}: {:?}", name, i, e);
            board::console(&line);
            board::exit(false);
        }
        let what = if scattered {
            "from one lattice point to another"
        } else {
            "warm start along the 2 kHz path"
        };
        let mut line: heapless::String<128> = heapless::String::new();
        let _ = write!(
            line,
            "# {}: {:.2} LM iterations per solve ({})",
            name,
            iterations as f32 / N as f32,
            what
        );
        board::console(&line);
        report(name, solve as f32 * per_count / N as f32);
    }
    board::exit(true)
}
