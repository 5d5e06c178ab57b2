//! Motion controller of the hidden-robot micro-mechanism: an RTIC 2 app.
//!
//! Features:
//! * **2 kHz servo step** in [`app::servo_tick`], bound to the board's hardware timer interrupt
//!   (`SERVO_TICK`, priority 3): read both encoders, take the next setpoint, hidden-robot IK,
//!   grid correction, PID with velocity/acceleration feed-forward per axis, write the torques
//!   (all of it `kinematics_core::Servo::step`).
//! * **Deadline monitoring**: every step measures its time from the tick and checks whether
//!   the next tick already came; overruns are counted, the worst step time kept, and a streak
//!   of overruns latches a fault.
//! * **Latched faults, safe state**: any fault (non-finite value, unreachable or singular
//!   setpoint, outside the grid, a setpoint jump beyond 5 g, following error, overrun streak,
//!   bad calibration image) disables the drives and commands zero torque in the same sample;
//!   only a reset clears it. A motor never jumps: the servo refuses, it never clamps a
//!   setpoint into reach.
//! * **Setpoint intake** ([`app::intake`], priority 2): keeps a `heapless` SPSC queue filled
//!   from the built-in trajectory (a host link would fill the same queue).
//! * **Telemetry** ([`app::telemetry`], priority 1): defmt status at 4 Hz; on QEMU it also
//!   evaluates the test scenario and ends the run with its verdict.
//! * **Fault handling** ([`app::on_fault`], priority 1): reports the latched fault.
//! * **Calibration**: the correction grid image is read from its own flash region and
//!   validated at boot; a bad or missing image keeps the drives disabled unless
//!   `Settings::allow_uncorrected` is set.
//! * Idle spins (QEMU) or sleeps (hardware); it never holds a resource, so it starves nothing.
#![no_std]
#![no_main]

#[cfg(feature = "board-g474")]
use defmt_rtt as _;

#[rtic::app(device = firmware::board::device, peripherals = false, dispatchers = [DISPATCH_1, DISPATCH_2])]
mod app {
    use heapless::spsc::{Consumer, Producer, Queue};
    use kinematics_core::{Calibration, Servo};

    use firmware::board::{self, Board};
    use firmware::calibration::{self, CalibrationState};
    use firmware::monitor::{Deadline, Fault, Status};
    use firmware::scenario::{self, Scenario};
    use firmware::settings::Settings;
    use firmware::trajectory::{Trajectory, WORKSPACE_TOUR_MM};
    use firmware::{SAMPLE_PERIOD_S, SAMPLE_RATE_HZ};

    /// Setpoint queue: 64 slots (63 usable), 31.5 ms of samples.
    const QUEUE_SLOTS: usize = 64;
    /// The servo task asks the intake for more when fewer setpoints than this are queued.
    const REFILL_BELOW: usize = 32;
    /// The servo deadline (µs): the next tick.
    const DEADLINE_US: f32 = 1.0e6 / SAMPLE_RATE_HZ as f32;

    /// Where the servo is.
    #[derive(Clone, Copy, Debug, PartialEq, defmt::Format)]
    pub enum Mode {
        /// Drives enabled, stepping.
        Running,
        /// Drives disabled, zero torque: a fault latched (at boot or while running).
        SafeState(Fault),
    }

    #[shared]
    struct Shared {
        status: Status,
    }

    #[local]
    struct Local {
        board: Board,
        servo: Servo,
        calibration: Calibration<'static>,
        mode: Mode,
        deadline: Deadline,
        setpoints_out: Consumer<'static, [f32; 2]>,
        setpoints_in: Producer<'static, [f32; 2]>,
        trajectory: Trajectory,
        scenario: Scenario,
        /// Setpoints queued so far (the sample index of the next one).
        queued: u32,
        /// Copies for the servo task.
        servo_settings: Settings,
        servo_scenario: Scenario,
        /// Copies for the telemetry task's checks.
        telemetry_scenario: Scenario,
        telemetry_calibration: Calibration<'static>,
        /// Sample at which the trajectory is done.
        trajectory_end_tick: u32,
        /// Last setpoint the servo was given (held when the queue runs empty).
        last_setpoint_mm: [f32; 2],
    }

    #[init(local = [queue: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let settings = Settings::default();
        let mut line = [0u8; 64];
        let scenario = Scenario::from_command_line(board::command_line(&mut line));
        defmt::info!("boot: scenario {}, settings {}", scenario, settings.servo);
        // Self-tests of the failure paths (QEMU scenarios only; the real board never gets
        // these on its empty command line): both must end the QEMU run with failure.
        match scenario {
            Scenario::Panic => {
                let v: Option<u32> = core::hint::black_box(None);
                let _ = v.expect("self-test: panic path");
            }
            Scenario::HardFault => cortex_m::asm::udf(),
            _ => {}
        }

        let mut board = Board::init(SAMPLE_RATE_HZ, settings.drive_full_scale_nm);
        let (cal_state, cal) = calibration::load(settings.allow_uncorrected);
        let mut status = Status::new(cal_state);
        let mut servo = Servo::new(settings.servo);

        // Engage at the machine's actual position, unless the calibration forbids it.
        let encoder_rad = board.encoders_rad();
        let engaged = match cal_state {
            CalibrationState::Refused(e) => {
                defmt::error!("calibration image refused ({}): drives stay disabled", e);
                Err(Fault::Calibration(e))
            }
            CalibrationState::Uncorrected(e) => {
                defmt::warn!("calibration image refused ({}): running UNCORRECTED", e);
                servo.engage(&cal, encoder_rad).map_err(Fault::Servo)
            }
            CalibrationState::Valid => servo.engage(&cal, encoder_rad).map_err(Fault::Servo),
        };
        let (mode, start_mm) = match engaged {
            Ok(tool_mm) => {
                defmt::info!("engaged at {} mm (encoders {} rad)", tool_mm, encoder_rad);
                board.enable_drives();
                status.drives_enabled = true;
                status.drives_ever_enabled = true;
                (Mode::Running, tool_mm)
            }
            Err(fault) => {
                board.disable_drives();
                status.fault = Some(fault);
                (Mode::SafeState(fault), [0.0; 2])
            }
        };
        status.setpoint_mm = start_mm;
        status.encoder_rad = encoder_rad;

        // No waypoints: hold the engaged position.
        let tour: &[[f32; 2]] = match scenario {
            Scenario::OutOfReach => &[[320.0, 0.0]],
            Scenario::Run if !settings.run_builtin_tour => &[],
            _ => &WORKSPACE_TOUR_MM,
        };
        let mut trajectory = Trajectory::new(
            start_mm,
            tour,
            settings.trajectory_accel_mm_s2,
            settings.trajectory_speed_mm_s,
            settings.trajectory_dwell_s,
            SAMPLE_PERIOD_S,
        );
        let trajectory_end_tick = trajectory.total_samples();
        let (mut setpoints_in, setpoints_out) = cx.local.queue.split();
        let mut queued = 0u32;
        if mode == Mode::Running {
            while setpoints_in.ready() {
                let p = scenario.tamper(queued, trajectory.next_mm());
                let _ = setpoints_in.enqueue(p);
                queued += 1;
            }
        }

        board.timer.start();
        (
            Shared { status },
            Local {
                board,
                servo,
                calibration: cal,
                mode,
                deadline: Deadline::default(),
                setpoints_out,
                setpoints_in,
                trajectory,
                scenario,
                queued,
                servo_settings: settings,
                servo_scenario: scenario,
                telemetry_scenario: scenario,
                telemetry_calibration: cal,
                trajectory_end_tick,
                last_setpoint_mm: start_mm,
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            board::idle_wait();
        }
    }

    /// The servo step, 2 kHz, on the board's servo timer interrupt (highest priority).
    ///
    /// **Deadline: 500 µs**, the next tick. The step measures its own time from the tick
    /// (`worst_step_us`) and, after writing the torques, checks whether the next tick is
    /// already pending. A missed deadline is counted (`overruns`); the torques written late
    /// still stand (they are the best available). `overrun_streak_limit` consecutive misses
    /// (default 3, i.e. 1.5 ms without a fresh command) latch `Fault::DeadlineMissed`: drives
    /// disabled, zero torque.
    #[task(binds = SERVO_TICK, priority = 3, shared = [status],
           local = [board, servo, calibration, mode, deadline, setpoints_out, last_setpoint_mm,
                   servo_settings, servo_scenario])]
    fn servo_tick(mut cx: servo_tick::Context) {
        let l = cx.local;
        l.board.timer.clear_interrupt();
        l.board.simulate_period();
        let encoder_rad = l.board.encoders_rad();
        let tick = cx.shared.status.lock(|s| s.ticks);

        let mut underrun = false;
        let mut following_error_rad = 0.0f32;
        let mut new_fault = None;
        let torque_nm = match *l.mode {
            Mode::Running => {
                let setpoint_mm = match l.setpoints_out.dequeue() {
                    Some(p) => p,
                    None => {
                        underrun = true;
                        *l.last_setpoint_mm
                    }
                };
                if l.setpoints_out.len() < REFILL_BELOW {
                    let _ = intake::spawn();
                }
                match l.servo.step(l.calibration, setpoint_mm, encoder_rad) {
                    Ok(out) => {
                        *l.last_setpoint_mm = setpoint_mm;
                        following_error_rad =
                            out.following_error_rad[0].abs().max(out.following_error_rad[1].abs());
                        match l.board.set_torques_nm(out.torque_nm) {
                            Some(t) => t,
                            None => {
                                new_fault = Some(Fault::Drive);
                                [0.0; 2]
                            }
                        }
                    }
                    Err(f) => {
                        new_fault = Some(Fault::Servo(f));
                        [0.0; 2]
                    }
                }
            }
            Mode::SafeState(_) => l.board.set_torques_nm([0.0; 2]).unwrap_or([0.0; 2]),
        };

        // Fault injection for the deadline test (QEMU scenario `overrun` only).
        if l.servo_scenario.overrun_at(tick) {
            l.board.timer.burn_until_us(1.4 * DEADLINE_US);
        }

        let step_us = l.board.timer.step_time_us();
        let overrun = l.board.timer.next_tick_pending();
        if l.deadline.record(step_us, overrun, l.servo_settings.overrun_streak_limit) && new_fault.is_none() {
            if let Mode::Running = *l.mode {
                new_fault = Some(Fault::DeadlineMissed);
            }
        }
        if let Some(fault) = new_fault {
            l.board.disable_drives();
            *l.mode = Mode::SafeState(fault);
            let _ = on_fault::spawn(fault);
        }

        let mode = *l.mode;
        let last_setpoint_mm = *l.last_setpoint_mm;
        let deadline = *l.deadline;
        cx.shared.status.lock(|s| {
            s.ticks = tick.wrapping_add(1);
            s.overruns = deadline.overruns;
            s.worst_step_us = deadline.worst_step_us;
            s.encoder_rad = encoder_rad;
            s.torque_nm = torque_nm;
            s.setpoint_mm = last_setpoint_mm;
            if underrun {
                s.setpoint_underruns += 1;
            }
            match mode {
                Mode::Running => {
                    s.max_following_error_rad = s.max_following_error_rad.max(following_error_rad);
                }
                Mode::SafeState(fault) => {
                    if s.fault.is_none() {
                        s.fault = Some(fault);
                        s.fault_tick = tick;
                    } else {
                        let t = torque_nm[0].abs().max(torque_nm[1].abs());
                        s.max_torque_after_fault_nm = s.max_torque_after_fault_nm.max(t);
                    }
                    s.drives_enabled = false;
                }
            }
        });
        if tick % l.servo_settings.telemetry_period_ticks.max(1) == 0 {
            let _ = telemetry::spawn();
        }
    }

    /// Setpoint intake: refills the queue from the trajectory (and applies the test
    /// scenario's tampering). Spawned by the servo task when the queue runs low.
    #[task(priority = 2, local = [setpoints_in, trajectory, scenario, queued])]
    async fn intake(cx: intake::Context) {
        let l = cx.local;
        while l.setpoints_in.ready() {
            let p = l.scenario.tamper(*l.queued, l.trajectory.next_mm());
            let _ = l.setpoints_in.enqueue(p);
            *l.queued += 1;
        }
    }

    /// Telemetry every `Settings::telemetry_period_ticks` samples; on QEMU also the
    /// scenario's verdict, which ends the run.
    #[task(priority = 1, shared = [status], local = [telemetry_scenario, telemetry_calibration, trajectory_end_tick])]
    async fn telemetry(mut cx: telemetry::Context) {
        let s = cx.shared.status.lock(|s| *s);
        defmt::info!(
            "t {} ms: fault {} overruns {} worst {} us, setpoint {} mm, encoders {} rad, torque {} Nm, max following error {} rad",
            s.ticks / (SAMPLE_RATE_HZ / 1000), s.fault, s.overruns, s.worst_step_us, s.setpoint_mm, s.encoder_rad, s.torque_nm,
            s.max_following_error_rad
        );
        let scenario = *cx.local.telemetry_scenario;
        match scenario::check(scenario, &s, cx.local.telemetry_calibration, *cx.local.trajectory_end_tick, DEADLINE_US) {
            None => {}
            Some(Ok(())) => {
                defmt::info!("PASS {}", scenario);
                board::console("PASS");
                board::exit(true);
            }
            Some(Err(why)) => {
                defmt::error!("FAIL {}: {}", scenario, why);
                board::console("FAIL");
                board::console(why);
                board::exit(false);
            }
        }
    }

    /// Fault handling: the safe state is already applied by the servo task in the sample that
    /// found the fault; this reports it.
    #[task(priority = 1, shared = [status])]
    async fn on_fault(mut cx: on_fault::Context, fault: Fault) {
        let s = cx.shared.status.lock(|s| *s);
        defmt::error!(
            "FAULT {} at sample {}: drives disabled, zero torque (setpoint {} mm, encoders {} rad)",
            fault, s.ticks, s.setpoint_mm, s.encoder_rad
        );
    }
}
