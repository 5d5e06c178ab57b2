//! One servo sample, without hardware: the mode machine, setpoint intake with underrun
//! handling, fault latching, and what torque and drive enable result.
//!
//! ```text
//!  boot ── image valid (or uncorrected allowed) and engage accepted ──► Running
//!    └──── image refused, or engage refused ──────────────────────────► SafeState(fault)
//!  Running ── servo refusal, PWM write error, overrun streak ─────────► SafeState(fault)
//!  boot after a watchdog reset, watchdog not started ([`ServoLoop::latch_at_boot`]) ─► SafeState
//! ```
//! `SafeState` is latched: zero torque, drive enable off, the queue left alone; only a reset
//! leaves it. The board-facing part of a sample is in the app (`firmware/src/main.rs`,
//! `servo_tick`): read encoders, [`ServoLoop::step`], write the torques (a failed write is
//! [`ServoLoop::latch`]ed as [`Fault::Drive`]), [`ServoLoop::record_deadline`], disable the drives
//! if the sample latched a fault, publish the [`Status`](crate::status::Status), and last feed
//! the watchdog if [`Sample::feed_watchdog`] (the step was on time; see [`crate::watchdog`]).
//!
//! A motor never jumps: the servo refuses a setpoint it cannot follow, it never clamps one into
//! reach, and a refusal removes torque in the same sample.
use heapless::spsc::Consumer;
use kinematics_core::{Calibration, Servo};

use crate::calibration::CalibrationState;
use crate::deadline::Deadline;
use crate::fault::Fault;
use crate::setpoints::REFILL_BELOW;
use crate::settings::Settings;
use crate::watchdog;

/// Where the servo is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// Drives enabled, stepping.
    Running,
    /// Drives disabled, zero torque: a fault latched (at boot or while running).
    SafeState(Fault),
}

/// What one sample decided, and what it saw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Index of the sample since the timer started (0 is the first).
    pub index: u32,
    /// The encoder angles it was given (rad).
    pub encoder_rad: [f32; 2],
    /// The last setpoint the servo accepted (mm): this sample's, or an earlier one after an
    /// underrun or a refusal.
    pub setpoint_mm: [f32; 2],
    /// The encoder angles commanded for [`Sample::setpoint_mm`] (rad).
    pub reference_rad: [f32; 2],
    /// Torques to write (N·m): zero in the safe state and in the sample that latched a fault.
    pub torque_nm: [f32; 2],
    /// Largest |following error| of the two axes this sample (rad; 0 when not stepping).
    pub following_error_rad: f32,
    /// The queue was empty: the last setpoint was held.
    pub underrun: bool,
    /// Fewer than [`REFILL_BELOW`] setpoints are left: the intake should refill the queue.
    pub refill: bool,
    /// The fault this sample latched (the loop was running before it).
    pub fault: Option<Fault>,
    /// The step completed on time: the servo task feeds the independent watchdog at its end.
    /// Set only by [`ServoLoop::record_deadline`] (a sample whose deadline was not recorded
    /// does not feed); in the safe state too (drives off is not a stall).
    pub feed_watchdog: bool,
}

/// The servo loop's state from one sample to the next.
#[derive(Clone, Debug)]
pub struct ServoLoop<'a> {
    settings: &'a Settings,
    calibration: Calibration<'a>,
    servo: Servo,
    mode: Mode,
    deadline: Deadline,
    setpoint_mm: [f32; 2],
    reference_rad: [f32; 2],
    samples: u32,
}

impl<'a> ServoLoop<'a> {
    /// Boots the loop: engages the servo at the machine's actual position (`encoder_rad`)
    /// unless the calibration forbids it. [`ServoLoop::mode`] tells the outcome: `Running`
    /// (enable the drives) or `SafeState` with the reason.
    pub fn boot(
        settings: &'a Settings,
        calibration: Calibration<'a>,
        state: CalibrationState,
        encoder_rad: [f32; 2],
    ) -> Self {
        let mut servo = Servo::new(settings.servo);
        let engaged = match state {
            CalibrationState::Refused(e) => Err(Fault::Calibration(e)),
            CalibrationState::Valid | CalibrationState::Uncorrected(_) => {
                servo.engage(&calibration, encoder_rad).map_err(Fault::Servo)
            }
        };
        let (mode, setpoint_mm) = match engaged {
            Ok(tool_mm) => (Mode::Running, tool_mm),
            Err(fault) => (Mode::SafeState(fault), [0.0; 2]),
        };
        ServoLoop {
            settings,
            calibration,
            servo,
            mode,
            deadline: Deadline::default(),
            setpoint_mm,
            reference_rad: encoder_rad,
            samples: 0,
        }
    }

    /// Running or safe state.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether the drives should be enabled (running).
    pub fn drives_enabled(&self) -> bool {
        self.mode == Mode::Running
    }

    /// The last setpoint accepted (mm); after boot, where the servo engaged: the first
    /// setpoint must be there.
    pub fn setpoint_mm(&self) -> [f32; 2] {
        self.setpoint_mm
    }

    /// The encoder angles commanded for [`ServoLoop::setpoint_mm`] (after boot, the encoder
    /// reading it engaged at).
    pub fn reference_rad(&self) -> [f32; 2] {
        self.reference_rad
    }

    /// Deadline bookkeeping so far.
    pub fn deadline(&self) -> &Deadline {
        &self.deadline
    }

    /// The settings the loop runs with.
    pub fn settings(&self) -> &'a Settings {
        self.settings
    }

    /// One sample: takes the next setpoint from `queue` (holding the last one if it is empty)
    /// and runs the servo step on `encoder_rad`. In the safe state the queue is left alone
    /// and the torques are zero.
    pub fn step(&mut self, queue: &mut Consumer<'_, [f32; 2]>, encoder_rad: [f32; 2]) -> Sample {
        let index = self.samples;
        self.samples = self.samples.wrapping_add(1);
        let mut sample = Sample {
            index,
            encoder_rad,
            setpoint_mm: self.setpoint_mm,
            reference_rad: self.reference_rad,
            torque_nm: [0.0; 2],
            following_error_rad: 0.0,
            underrun: false,
            refill: false,
            fault: None,
            feed_watchdog: false,
        };
        if self.mode != Mode::Running {
            return sample;
        }
        let setpoint_mm = match queue.dequeue() {
            Some(p) => p,
            None => {
                sample.underrun = true;
                self.setpoint_mm
            }
        };
        sample.refill = queue.len() < REFILL_BELOW;
        match self.servo.step(&self.calibration, setpoint_mm, encoder_rad) {
            Ok(out) => {
                self.setpoint_mm = setpoint_mm;
                self.reference_rad = out.reference_rad;
                sample.setpoint_mm = setpoint_mm;
                sample.reference_rad = out.reference_rad;
                sample.torque_nm = out.torque_nm;
                sample.following_error_rad =
                    out.following_error_rad[0].abs().max(out.following_error_rad[1].abs());
            }
            Err(f) => self.latch(Fault::Servo(f), &mut sample),
        }
        sample
    }

    /// Latches `fault` (if the loop is still running) and zeroes the sample's torques. The
    /// caller disables the drives when `sample.fault` is set.
    pub fn latch(&mut self, fault: Fault, sample: &mut Sample) {
        if self.mode == Mode::Running {
            self.mode = Mode::SafeState(fault);
            sample.fault = Some(fault);
        }
        sample.torque_nm = [0.0; 2];
    }

    /// Records how long the sample took (`step_us` from its tick) and whether the next tick
    /// already came; a streak of `overrun_streak_limit` misses latches
    /// [`Fault::DeadlineMissed`]. The torques already written stand until the drives are
    /// disabled (they were the best available). Sets [`Sample::feed_watchdog`] when the step
    /// was on time ([`watchdog::step_on_time`]).
    pub fn record_deadline(&mut self, step_us: f32, overrun: bool, sample: &mut Sample) {
        if self.deadline.record(step_us, overrun, self.settings.overrun_streak_limit) && self.mode == Mode::Running {
            self.latch(Fault::DeadlineMissed, sample);
        }
        sample.feed_watchdog = watchdog::step_on_time(step_us, overrun);
    }

    /// Keeps the drives off from boot, before the first sample, with `fault` (e.g. the last
    /// reset was the watchdog's, or the watchdog could not be started). A fault already
    /// latched at boot (a refused image) stays the one reported.
    pub fn latch_at_boot(&mut self, fault: Fault) {
        if self.mode == Mode::Running {
            self.mode = Mode::SafeState(fault);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use heapless::spsc::Queue;
    use kinematics_core::grid::{encode, CorrectionGrid, GridGeometry};
    use kinematics_core::{FiveBar, GridError, ServoFault};

    use crate::setpoints::QUEUE_SLOTS;

    const HOME_MM: [f32; 2] = [212.132, 0.0];

    fn image() -> Vec<u8> {
        let g = GridGeometry { nx: 3, ny: 3, x0_mm: 160.0, y0_mm: -80.0, step_x_mm: 50.0, step_y_mm: 80.0 };
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, &g, &FiveBar::paper_nominal(), &[[3e-4, -2e-4]; 9]).unwrap();
        img
    }

    /// Boots on a valid image with the machine at the home pose.
    fn running<'a>(settings: &'a Settings, img: &'a [u8]) -> (ServoLoop<'a>, [f32; 2]) {
        let cal = Calibration::from_grid(CorrectionGrid::parse(img).unwrap());
        let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
        let l = ServoLoop::boot(settings, cal, CalibrationState::Valid, encoder);
        assert_eq!(l.mode(), Mode::Running);
        (l, encoder)
    }

    #[test]
    fn boot_engages_where_the_machine_is() {
        let (settings, img) = (Settings::default(), image());
        let (l, encoder) = running(&settings, &img);
        assert!(l.drives_enabled());
        let p = l.setpoint_mm();
        assert!((p[0] - HOME_MM[0]).abs() < 1e-3 && (p[1] - HOME_MM[1]).abs() < 1e-3, "{p:?}");
        assert_eq!(l.reference_rad(), encoder);
    }

    #[test]
    fn a_refused_image_keeps_the_loop_safe_and_leaves_the_queue_alone() {
        let settings = Settings::default();
        let cal = Calibration { model: FiveBar::paper_nominal(), grid: None };
        let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Refused(GridError::BadCrc), encoder);
        assert_eq!(l.mode(), Mode::SafeState(Fault::Calibration(GridError::BadCrc)));
        assert!(!l.drives_enabled());
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(HOME_MM).unwrap();
        for _ in 0..3 {
            let s = l.step(&mut rx, encoder);
            assert_eq!(s.torque_nm, [0.0; 2]);
            assert_eq!((s.fault, s.underrun, s.refill), (None, false, false));
        }
        assert_eq!(rx.len(), 1, "nothing taken from the queue in the safe state");
        // Uncorrected running allowed: engages with the nominal model.
        let l = ServoLoop::boot(&settings, cal, CalibrationState::Uncorrected(GridError::BadCrc), encoder);
        assert_eq!(l.mode(), Mode::Running);
    }

    #[test]
    fn boot_refuses_an_encoder_reading_the_kinematics_refuse() {
        // Encoder zero: both arms stretched along x, the distal links cannot meet.
        let (settings, img) = (Settings::default(), image());
        let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
        let l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
        assert!(matches!(l.mode(), Mode::SafeState(Fault::Servo(ServoFault::Kinematics(_)))), "{:?}", l.mode());
    }

    #[test]
    fn a_refused_setpoint_latches_with_zero_torque_in_its_own_sample() {
        let (settings, img) = (Settings::default(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        // A small offset so the PID commands torque before the fault.
        tx.enqueue(HOME_MM).unwrap();
        tx.enqueue([f32::NAN, 0.0]).unwrap();
        tx.enqueue(HOME_MM).unwrap();
        let off = [encoder[0] + 1e-3, encoder[1]];
        let s = l.step(&mut rx, off);
        assert!(s.torque_nm[0] != 0.0 && s.fault.is_none());
        let s = l.step(&mut rx, off);
        assert_eq!(s.fault, Some(Fault::Servo(ServoFault::NonFiniteSetpoint)));
        assert_eq!(s.torque_nm, [0.0; 2]);
        assert_eq!(s.setpoint_mm, HOME_MM, "the last accepted setpoint, not the NaN");
        assert_eq!(l.mode(), Mode::SafeState(Fault::Servo(ServoFault::NonFiniteSetpoint)));
        let s = l.step(&mut rx, off);
        assert_eq!((s.fault, s.torque_nm), (None, [0.0; 2]), "latched once, zero ever after");
        assert_eq!(rx.len(), 1);
    }

    #[test]
    fn an_empty_queue_holds_the_last_setpoint_and_asks_for_a_refill() {
        let (settings, img) = (Settings::default(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let s = l.step(&mut rx, encoder);
        assert!(s.underrun && s.refill && s.fault.is_none());
        assert_eq!(s.setpoint_mm, l.setpoint_mm());
        while tx.ready() {
            tx.enqueue(l.setpoint_mm()).unwrap();
        }
        let s = l.step(&mut rx, encoder);
        assert!(!s.underrun && !s.refill, "{} left", rx.len());
        while rx.len() >= REFILL_BELOW {
            rx.dequeue();
        }
        assert!(l.step(&mut rx, encoder).refill);
    }

    #[test]
    fn a_streak_of_overruns_latches_deadline_missed_once() {
        let (settings, img) = (Settings::default(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (_, mut rx) = q.split();
        for k in 0..settings.overrun_streak_limit {
            let mut s = l.step(&mut rx, encoder);
            l.record_deadline(700.0, true, &mut s);
            let last = k + 1 == settings.overrun_streak_limit;
            assert_eq!(s.fault, last.then_some(Fault::DeadlineMissed), "overrun {k}");
        }
        assert_eq!(l.mode(), Mode::SafeState(Fault::DeadlineMissed));
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(700.0, true, &mut s);
        assert_eq!(s.fault, None, "already safe: nothing new latched");
        assert_eq!(l.deadline().overruns, settings.overrun_streak_limit + 1);
    }

    #[test]
    fn only_an_on_time_step_feeds_the_watchdog_and_the_safe_state_still_does() {
        let (settings, img) = (Settings::default(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (_, mut rx) = q.split();
        let s = l.step(&mut rx, encoder);
        assert!(!s.feed_watchdog, "no deadline recorded, no feed");
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(15.0, false, &mut s);
        assert!(s.feed_watchdog);
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(700.0, true, &mut s);
        assert!(!s.feed_watchdog, "late");
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(f32::NAN, false, &mut s);
        assert!(!s.feed_watchdog, "step time unreadable");
        // In the safe state the drives are off and the task still runs on time: it feeds.
        l.latch(Fault::Drive, &mut s);
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(10.0, false, &mut s);
        assert!(s.feed_watchdog && !l.drives_enabled());
    }

    #[test]
    fn a_fault_at_boot_keeps_the_drives_off_and_the_first_reason_is_kept() {
        use crate::watchdog::WatchdogFault;
        let (settings, img) = (Settings::default(), image());
        let (mut l, encoder) = running(&settings, &img);
        l.latch_at_boot(Fault::Watchdog(WatchdogFault::Reset));
        assert_eq!(l.mode(), Mode::SafeState(Fault::Watchdog(WatchdogFault::Reset)));
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(HOME_MM).unwrap();
        let s = l.step(&mut rx, [encoder[0] + 1e-3, encoder[1]]);
        assert_eq!((s.torque_nm, s.fault), ([0.0; 2], None));
        // A refused image at boot stays the reason reported.
        let cal = Calibration { model: FiveBar::paper_nominal(), grid: None };
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Refused(GridError::BadCrc), encoder);
        l.latch_at_boot(Fault::Watchdog(WatchdogFault::NotStarted));
        assert_eq!(l.mode(), Mode::SafeState(Fault::Calibration(GridError::BadCrc)));
    }

    #[test]
    fn a_failed_pwm_write_latches_a_drive_fault() {
        let (settings, img) = (Settings::default(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (_, mut rx) = q.split();
        let mut s = l.step(&mut rx, [encoder[0] + 1e-3, encoder[1]]);
        assert!(s.torque_nm[0] != 0.0);
        l.latch(Fault::Drive, &mut s);
        assert_eq!((s.fault, s.torque_nm), (Some(Fault::Drive), [0.0; 2]));
        assert!(!l.drives_enabled());
    }

    #[test]
    fn the_reference_is_model_ik_plus_the_grid_correction() {
        let (settings, img) = (Settings::default(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<[f32; 2], QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(HOME_MM).unwrap();
        let s = l.step(&mut rx, encoder);
        assert!(s.fault.is_none());
        let ik = FiveBar::<f32>::paper_nominal().inverse(HOME_MM, 0.05).unwrap();
        assert!((s.reference_rad[0] - ik[0] - 3e-4).abs() < 1e-6, "{:?} vs {ik:?}", s.reference_rad);
        assert!((s.reference_rad[1] - ik[1] + 2e-4).abs() < 1e-6);
    }
}
