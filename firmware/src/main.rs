//! Motion controller of the hidden-robot micro-mechanism: an RTIC 2 app.
//!
//! Features:
//! * **2 kHz servo step** in [`app::servo_tick`], bound to the board's hardware timer interrupt
//!   (`SERVO_TICK`, priority 3): read both encoders, take the next setpoint (with its exact
//!   velocity, acceleration and jerk), hidden-robot IK and joint motion, grid correction,
//!   inverse-dynamics feed-forward (the image's identified parameters) and a PID per axis on
//!   the remainder, write the torques (`controller::servo_loop::ServoLoop::step` around
//!   `kinematics_core::Servo::step_motion`).
//! * **Deadline monitoring**: every step measures its time from the tick and checks whether
//!   the next tick already came; overruns are counted, the worst step time kept, and a streak
//!   of overruns latches a fault.
//! * **Stop categories** (IEC 60204-1; table in `controller::fault`): a fault of the setpoint
//!   stream (non-finite, unreachable, singular or outside-grid setpoint, a jump beyond 5 g, a
//!   setpoint whose stop would leave the workspace, the queue running dry while moving) brakes
//!   the machine along its path at 5 g, jerk-limited, from the very sample that found it, then
//!   holds the position (category 2) or, after a non-finite setpoint, removes torque at
//!   standstill (category 1). A fault of the feedback or the controller (encoder implausible,
//!   stuck or glitching, following error, overrun streak, PWM write error) disables the drives
//!   and commands zero torque in the same sample (category 0). Only a reset clears a fault. A
//!   motor never jumps: the servo refuses, it never clamps a setpoint into reach.
//! * **Encoder plausibility** (`controller::encoder_check`): speed and acceleration beyond the
//!   mechanism's, glitches, a reading that does not move under torque, at rest too.
//! * **Independent watchdog** (3 ms), fed last in the servo task and only after an on-time
//!   step (`controller::watchdog`): a stalled servo task lets it expire (category 0; G474:
//!   reset; QEMU: NMI that removes torque, then reset). The boot after a watchdog reset keeps
//!   the drives off; the reset cause is logged at every boot.
//! * **Setpoint intake** ([`app::intake`], priority 2): keeps a `heapless` SPSC queue filled
//!   from the board's setpoint source, the built-in jerk-limited trajectory (a host link would
//!   fill the same queue).
//! * **Host link** ([`app::link_rx`], priority 1, the link UART's receive interrupt, also pended
//!   every 5 ms): framed, checksummed requests (`link-protocol`), one reply each
//!   (`controller::host_link`): identify, status, enable/disable, home, move, streamed motion
//!   into the [`MotionStream`](controller::motion_stream::MotionStream), stop, reset,
//!   telemetry, calibration. Requests for the servo (stop, disable, reset) are posted and
//!   applied by the servo task at its next sample. With `Settings::link_motion` the intake
//!   plays the link's motion instead of the built-in tour.
//! * **Telemetry** ([`app::telemetry`], priority 1): defmt status at 4 Hz.
//! * **Fault handling** ([`app::on_fault`], priority 1): reports the latched fault.
//! * **Calibration and machine**: the correction grid image is read from its own flash region
//!   and judged at boot against the machine record it carries; that record is the machine the
//!   run drives (`Settings::machine`, `controller::calibration`). A bad or missing image keeps
//!   the drives disabled unless `Settings::allow_uncorrected` is set. An upload's commit
//!   judges the new image against that machine in the link task (priority 1).
//! * Idle waits for interrupts (the QEMU board spins); it never holds a resource.
//!
//! The board (`firmware::board::Selected`, a `Board`) is the only thing that differs between
//! the STM32G474 and QEMU; the QEMU board's per-sample hooks step its simulated plant and run
//! the test harness, which this file knows nothing about.
#![no_std]
#![no_main]

#[cfg(feature = "board-g474")]
use defmt_rtt as _;

#[rtic::app(device = firmware::board::device, peripherals = false, dispatchers = [DISPATCH_1, DISPATCH_2])]
mod app {
    use heapless::spsc::{Consumer, Producer, Queue};
    use kinematics_core::trajectory::MotionSetpoint;

    use controller::calibration::{self, CalibrationState};
    use controller::calibration_slots::{CalibrationId, SlotStore};
    use controller::fault::{Fault, StopCategory};
    use controller::host_link::LinkHandler;
    use controller::motion_stream::{MotionStream, StreamLimits};
    use controller::servo_loop::{Mode, Sample, ServoLoop, ServoRequest};
    use controller::setpoints::{self, QUEUE_SLOTS};
    use controller::settings::Settings;
    use controller::status::Status;
    use controller::SAMPLE_RATE_HZ;
    use firmware::board::{Board, IndexOf, Selected, ServoTimer};
    use firmware::calibration::RegionFlash;
    use firmware::link::{LinkFacts, LinkState, Locks};
    use kinematics_core::Calibration;
    use link_protocol::FrameReader;

    /// The servo task pends the link task every this many samples (5 ms), so that a paused
    /// motion source resumes and telemetry goes out even when the host sends nothing.
    const LINK_POLL_TICKS: u32 = 10;

    #[shared]
    struct Shared {
        status: Status,
        /// The host link's motion source (link task: queues; intake task: plays).
        stream: MotionStream,
        /// A host request for the servo task, applied at the start of its next sample.
        servo_request: Option<ServoRequest>,
        /// The host link's port, reader, handler (link and telemetry tasks).
        link: LinkState<<Selected as Board>::Link>,
        /// The calibration slots (the link task's upload, and the QEMU upload scenarios' task,
        /// write the inactive one, both at priority 1).
        slots: SlotStore<RegionFlash>,
        /// A newly committed calibration for the servo task to switch to at rest.
        new_calibration: Option<(Calibration<'static>, CalibrationId)>,
    }

    #[local]
    struct Local {
        board: Selected,
        servo_loop: ServoLoop<'static>,
        setpoints_out: Consumer<'static, MotionSetpoint<f32>>,
        setpoints_in: Producer<'static, MotionSetpoint<f32>>,
        source: <Selected as Board>::Setpoints,
        link_motion: bool,
    }

    #[init(local = [
        queue: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new(),
        settings: Option<Settings> = None,
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        // The machine: the image in force, the committed slot with the highest sequence or an
        // image flashed by probe at the region's start (controller::calibration_slots), judged
        // against its own machine record (the board's built-in machine if it carries none);
        // its record is the machine this run drives (controller::calibration). Before the
        // board: the settings it is given are the machine's.
        let board_settings = Selected::settings();
        let slots = SlotStore::open(firmware::calibration::flash(), board_settings.image_check());
        let calibration_id = slots.active_id();
        let image = calibration_id.map_or(
            firmware::calibration::region(),
            firmware::calibration::slot_bytes,
        );
        let loaded = calibration::load(
            image,
            &board_settings.image_check(),
            board_settings.allow_uncorrected,
        );
        // One copy of the settings for the whole run, borrowed by every task.
        let settings: &'static Settings = cx
            .local
            .settings
            .insert(board_settings.for_machine(&loaded.machine));
        defmt::info!("boot: settings {}", settings.servo);
        let mut board = Selected::init(settings);
        let reset_cause = board.reset_cause();
        defmt::info!("boot: reset cause {}", reset_cause);
        defmt::info!("boot: calibration in force {}", calibration_id);
        let machine = &settings.machine;
        defmt::info!(
            "boot: machine '{}' (digest {=u32:#x}), home {} mm",
            machine.name.as_str(),
            machine.digest(),
            machine.home_mm
        );
        let (cal_state, cal) = (loaded.state, loaded.calibration);
        match cal_state {
            CalibrationState::Valid => {}
            CalibrationState::Refused(e) => {
                defmt::error!("calibration image refused ({}): drives stay disabled", e)
            }
            CalibrationState::Uncorrected(e) => {
                defmt::warn!("calibration image refused ({}): running UNCORRECTED", e)
            }
        }
        // Engage at the machine's actual position, unless the calibration forbids it.
        let encoder_rad = board.encoders_rad();
        let mut servo_loop = ServoLoop::boot(settings, cal, cal_state, encoder_rad);
        // A watchdog reset keeps the drives off.
        if let Some(fault) = Fault::after_reset(reset_cause) {
            servo_loop.latch_at_boot(fault);
        }
        // Incremental encoders: homing first (at boot if the settings say so; otherwise the
        // host's Home command starts it). The stream then starts at the home position.
        let unhomed = servo_loop.mode() == Mode::Unhomed;
        if unhomed && settings.homing.at_boot {
            match servo_loop.start_homing(encoder_rad) {
                Ok(()) => defmt::info!("homing at boot from encoders {} rad", encoder_rad),
                Err(mode) => defmt::error!("homing refused: {}", mode),
            }
        }
        let start_mm = if unhomed {
            settings.home_mm()
        } else {
            servo_loop.setpoint_mm()
        };
        let mut source = board.setpoints(settings.builtin_trajectory(start_mm));
        // The link's port, configured before the watchdog starts: bringing a UART up may wait
        // for its acknowledgement (G474: a bounded wait of a few ms at most).
        let port = board.link();
        // The watchdog starts only now, after the slow part of the boot (the QEMU harness scans
        // the trajectory), so that the first servo sample comes well within its timeout; a
        // watchdog that will not start keeps the drives off.
        if let Err(e) = board.start_watchdog() {
            servo_loop.latch_at_boot(Fault::Watchdog(e));
        }
        match (servo_loop.mode(), servo_loop.mode().fault()) {
            (Mode::Running, _) => {
                defmt::info!(
                    "engaged at {} mm (encoders {} rad)",
                    servo_loop.setpoint_mm(),
                    encoder_rad
                );
                board.enable_drives();
            }
            (Mode::Homing, _) => board.enable_drives(),
            (Mode::Unhomed, _) => {
                defmt::warn!("not homed: drives disabled until homing (every setpoint refused)");
                board.disable_drives();
            }
            (_, fault) => {
                defmt::error!("not engaged ({}): drives disabled", fault);
                board.disable_drives();
            }
        }

        let limits = StreamLimits {
            task: settings.stream_limits(),
            knots: settings.knot_limits(),
            stop: settings.stop.limits,
            workspace: servo_loop.calibration().workspace(),
        };
        let mut stream = MotionStream::new(limits, start_mm);
        if servo_loop.mode() != Mode::Running {
            // Unhomed, homing or faulted: the stream waits, paused, until the servo runs; the link then
            // resumes it where the servo engaged (homing ends near, not exactly at, home).
            stream.pause();
        }
        let (mut setpoints_in, setpoints_out) = cx.local.queue.split();
        if servo_loop.drives_enabled() {
            if settings.link_motion {
                setpoints::refill(&mut setpoints_in, &mut stream);
            } else {
                setpoints::refill(&mut setpoints_in, &mut source);
            }
        }
        let link = LinkState {
            port,
            reader: FrameReader::new(),
            handler: LinkHandler::new(),
            facts: LinkFacts {
                absolute_encoders: settings.homing.absolute_encoders,
                link_motion: settings.link_motion,
                board: firmware::board::BOARD_ID,
                machine: controller::host_link::machine_id(machine),
            },
        };
        if settings.link_motion {
            defmt::info!("setpoints from the host link");
        }
        let status = Status {
            calibration_id,
            ..Status::at_boot(cal_state, &servo_loop, encoder_rad)
        };
        board.timer().start();
        let link_motion = settings.link_motion;
        (
            Shared {
                status,
                stream,
                servo_request: None,
                link,
                slots,
                new_calibration: None,
            },
            Local {
                board,
                servo_loop,
                setpoints_out,
                setpoints_in,
                source,
                link_motion,
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            Selected::idle_wait();
        }
    }

    /// The servo step, 2 kHz, on the board's servo timer interrupt (highest priority).
    ///
    /// **Deadline: 500 µs**, the next tick. The step measures its own time from the tick
    /// (`worst_step_us`) and, after writing the torques, checks whether the next tick is
    /// already pending. A missed deadline is counted (`overruns`); the torques written late
    /// still stand (they are the best available). `overrun_streak_limit` consecutive misses
    /// (default 3, i.e. 1.5 ms without a fresh command) latch `Fault::DeadlineMissed`: drives
    /// disabled, zero torque (category 0). Last, an on-time step feeds the independent watchdog
    /// (3 ms).
    #[task(binds = SERVO_TICK, priority = 3, shared = [status, servo_request, new_calibration], local = [board, servo_loop, setpoints_out])]
    fn servo_tick(mut cx: servo_tick::Context) {
        let l = cx.local;
        l.board.timer().acknowledge_tick();
        l.board.begin_sample();
        // Encoders -> the host's request, a committed calibration, the sample logic.
        let encoder_rad = l.board.encoders_rad();
        let request = cx.shared.servo_request.lock(Option::take);
        let offered = cx.shared.new_calibration.lock(Option::take);
        let index = &mut IndexOf(&mut *l.board);
        let tick = l
            .servo_loop
            .tick(request, offered, l.setpoints_out, encoder_rad, index);
        let mut sample = tick.sample;
        if tick.enable_drives {
            l.board.enable_drives();
        }
        // Drives, then the deadline.
        if l.board.set_torques_nm(sample.torque_nm).is_err() {
            l.servo_loop.latch(Fault::Drive, &mut sample);
        }
        let timer = l.board.timer();
        let (step_us, overrun) = (timer.step_time_us(), timer.next_tick_pending());
        l.servo_loop.record_deadline(step_us, overrun, &mut sample);
        // Safe state in the sample that decided it (category 0 at once; category 1 at
        // standstill after its stop).
        if sample.torque_off {
            l.board.disable_drives();
        }
        cx.shared.status.lock(|s| {
            s.publish(&sample, l.servo_loop, tick.switch);
            l.board.end_sample(s);
        });
        spawn_tasks(&sample, l.servo_loop.settings(), l.board);
        // Watchdog, last: only a step that completed on time feeds it.
        if sample.feed_watchdog {
            l.board.feed_watchdog();
        }
    }

    /// What the servo task starts after a sample: the intake when the queue runs low, the fault
    /// report, and every few samples telemetry, the link task's poll (so that a paused motion
    /// source resumes and telemetry goes out even when the host sends nothing), and a run-time
    /// upload the board asks for (the QEMU upload scenarios; never on hardware).
    fn spawn_tasks(sample: &Sample, settings: &Settings, board: &mut Selected) {
        if sample.refill {
            let _ = intake::spawn();
        }
        if let Some(fault) = sample.fault {
            let _ = on_fault::spawn(fault);
        }
        let index = sample.index;
        if index % settings.telemetry_period_ticks.max(1) == 0 {
            let _ = telemetry::spawn();
        }
        if index % LINK_POLL_TICKS == 0 {
            rtic::pend(firmware::board::device::Interrupt::LINK_RX);
        }
        if let Some((image, corrupt)) = board.bundled_upload_due(index) {
            let _ = upload::spawn(image, corrupt);
        }
    }

    /// Setpoint intake: refills the queue from the board's setpoint source. Spawned by the
    /// servo task when the queue runs low.
    #[task(priority = 2, shared = [stream], local = [setpoints_in, source, link_motion])]
    async fn intake(mut cx: intake::Context) {
        if *cx.local.link_motion {
            let queue = cx.local.setpoints_in;
            cx.shared
                .stream
                .lock(|stream| setpoints::refill(queue, stream));
        } else {
            setpoints::refill(cx.local.setpoints_in, cx.local.source);
        }
    }

    /// The host link (priority 1, below the intake and the servo task): on the port's receive
    /// interrupt, and pended by the servo task every [`LINK_POLL_TICKS`] samples. Drains the
    /// port, answers every frame (`controller::host_link`), resumes a paused motion source,
    /// sends due telemetry. Its locks on the stream hold off the intake (priority 2) for a
    /// frame's validation at most, never the servo task.
    #[task(binds = LINK_RX, priority = 1, shared = [status, stream, servo_request, link, slots, new_calibration])]
    fn link_rx(cx: link_rx::Context) {
        let link_rx::SharedResources {
            status,
            stream,
            servo_request,
            mut link,
            slots,
            new_calibration,
            ..
        } = cx.shared;
        let mut locks = Locks {
            status,
            request: servo_request,
            stream,
            slots,
            new_calibration,
        };
        link.lock(|link| {
            link.serve(&mut locks);
            link.poll(&mut locks);
        });
    }

    /// Telemetry every `Settings::telemetry_period_ticks` samples.
    #[task(priority = 1, shared = [status])]
    async fn telemetry(mut cx: telemetry::Context) {
        let s = cx.shared.status.lock(|s| *s);
        defmt::info!(
            "t {} ms: {} fault {} overruns {} worst {} us, setpoint {} mm, encoders {} rad, torque {} Nm, max following error {} rad",
            s.ticks / (SAMPLE_RATE_HZ / 1000), s.mode, s.fault, s.overruns, s.worst_step_us, s.setpoint_mm, s.encoder_rad, s.torque_nm,
            s.max_following_error_rad
        );
    }

    /// A calibration upload into the inactive slot (`controller::calibration_slots`): erase,
    /// write in chunks, validate and commit; on success the image is parsed here and handed to
    /// the servo task, which switches at rest. Low priority: flash writes never delay the servo.
    /// `corrupt` flips one bit on the way (the QEMU scenario of a damaged transfer). The host
    /// link's upload command drives the same `begin` / `write` / `commit`.
    #[task(priority = 1, shared = [slots, new_calibration, status])]
    async fn upload(mut cx: upload::Context, image: &'static [u8], corrupt: bool) {
        const CHUNK: usize = 200;
        let in_use = cx.shared.status.lock(|s| s.calibration_id);
        let result = cx.shared.slots.lock(|slots| {
            slots.begin(image.len(), in_use)?;
            let mut buf = [0u8; CHUNK];
            for (k, chunk) in image.chunks(CHUNK).enumerate() {
                let part = &mut buf[..chunk.len()];
                part.copy_from_slice(chunk);
                if corrupt && k == 1 {
                    part[7] ^= 0x40;
                }
                slots.write(k * CHUNK, part)?;
            }
            slots.commit()
        });
        match result {
            Ok(id) => {
                defmt::info!("calibration upload committed: {}", id);
                if let Some(new) = firmware::calibration::committed(id) {
                    cx.shared.new_calibration.lock(|n| *n = Some(new));
                }
            }
            Err(e) => defmt::error!(
                "calibration upload refused: {} (the image in force stays)",
                e
            ),
        }
        cx.shared.status.lock(|s| s.last_upload = Some(result));
    }

    /// Fault handling: the reaction (the stop, or the safe state) is already under way from
    /// the servo task's sample that found the fault; this reports it.
    #[task(priority = 1, shared = [status])]
    async fn on_fault(mut cx: on_fault::Context, fault: Fault) {
        let s = cx.shared.status.lock(|s| *s);
        let reaction = match fault.stop_category() {
            StopCategory::Zero => "category 0: drives disabled, zero torque",
            StopCategory::One => "category 1: braking along the path, then torque off",
            StopCategory::Two => "category 2: braking along the path, then holding",
        };
        defmt::error!(
            "FAULT {} at sample {}: {} (setpoint {} mm, encoders {} rad)",
            fault,
            s.ticks,
            reaction,
            s.setpoint_mm,
            s.encoder_rad
        );
    }
}
