//! The host's requests to the servo loop ([`ServoRequest`]), applied by the servo task at the
//! start of a sample ([`ServoLoop::request`]; the link's task only posts them).
//!
//! # What `Reset` does, per mode
//!
//! | mode | fault | `Reset` | drives | cleared |
//! |---|---|---|---|---|
//! | `Running` | none | nothing | on | nothing |
//! | `Stopping` | any | refused ([`ResetRefusal::Stopping`]): reset once the stop has ended | on | nothing |
//! | `Holding`, `SafeState` | settings, calibration refused at boot, watchdog not started | refused ([`ResetRefusal::Permanent`]): only a reboot clears it | unchanged | nothing |
//! | `Holding`, `SafeState` | any other, homed (or absolute encoders) | re-engages where the machine is: `Running`, at rest at the tool's position | on | the fault, the stop, the blend of a calibration switch, the queued setpoints, the encoder check's history, the last torque |
//! | `SafeState` | any other, never homed | back to `Unhomed` (Home again, no reboot) | off | the fault, the stop, the blend, the queued setpoints, homing |
//! | `Holding` | any other, never homed | refused ([`ResetRefusal::NotHomed`]) (cannot happen: holding needs an engaged servo) | on | nothing |
//! | `Unhomed`, `Homing` | none | nothing (homing decides when the servo engages) | unchanged | nothing |
//! | any | re-engaging refused at the reading ([`ResetRefusal::Engage`]) | refused, the mode unchanged | unchanged | nothing |
//!
//! A calibration committed and not yet switched to stays pending through a reset: the switch
//! happens at the first rest after it. The host link pauses its motion source on every request
//! and resumes it at the servo's setpoint once the loop runs again, so no setpoint planned
//! before the stop reaches the servo. `firmware/controller/src/servo_loop/tests.rs`'s
//! `reset_table` checks every cell, for every fault, from each mode.
use heapless::spsc::Consumer;
use kinematics_core::trajectory::MotionSetpoint;

use super::{Mode, ServoLoop};
use crate::encoder_check::EncoderCheck;
use crate::fault::Fault;
use crate::stop::MotionState;

/// What the host link asks of the servo loop ([`ServoLoop::request`]). The servo task applies
/// it at the start of a sample, before the step (the link's task only posts it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ServoRequest {
    /// Controlled stop, then hold ([`Fault::StopCommanded`], category 2).
    Stop,
    /// Controlled stop, then torque off ([`Fault::DisableCommanded`], category 1).
    Disable,
    /// Clear the latched fault and re-engage where the machine is (the module's table).
    Reset,
    /// Start homing ([`ServoLoop::start_homing`]): only from `Unhomed`.
    Home,
}

/// Why [`ServoRequest::Reset`] was refused; the mode is unchanged.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetRefusal {
    /// A controlled stop is under way: reset once it has ended.
    Stopping,
    /// The fault cannot be cleared without a reboot (settings or calibration refused at boot,
    /// or the watchdog could not be started: no motion without it).
    Permanent(Fault),
    /// The servo would not engage at the machine's position.
    Engage(kinematics_core::EngageError),
    /// Incremental encoders and homing never reached home, and the drives are on (a machine
    /// in the safe state instead goes back to `Unhomed`, see [`ServoLoop::request`]): the
    /// encoder zero is unknown, nothing engages.
    NotHomed,
}

impl<'a> ServoLoop<'a> {
    /// Applies a host link request (see [`ServoRequest`]) before this sample's step.
    /// `Stop` and `Disable` start the controlled stop while running (from the last accepted
    /// setpoint, as a fault would) and do nothing otherwise (`Disable` while holding removes
    /// torque at once: the machine is at rest). `Reset`: the module's table (`queue`: the
    /// setpoints planned before the stop, dropped). `Home` starts homing from `Unhomed`
    /// ([`ServoLoop::start_homing`]: the drives go on) and does nothing in any other mode (a
    /// refused plan latches its fault there). Returns whether the drives must be enabled now
    /// (they were off).
    pub fn request(
        &mut self,
        request: ServoRequest,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
    ) -> Result<bool, ResetRefusal> {
        let mut scratch = self.undecided_sample(encoder_rad);
        let fault = match (request, self.mode) {
            (ServoRequest::Stop, Mode::Running) => Fault::StopCommanded,
            (ServoRequest::Disable, Mode::Running | Mode::Holding(_)) => Fault::DisableCommanded,
            (ServoRequest::Stop | ServoRequest::Disable, _)
            | (ServoRequest::Reset, Mode::Running) => return Ok(false),
            // The drives go on with the homing search (its torque is limited).
            (ServoRequest::Home, _) => return Ok(self.start_homing(encoder_rad).is_ok()),
            (ServoRequest::Reset, Mode::Stopping(_)) => return Err(ResetRefusal::Stopping),
            // Homing decides when the servo engages.
            (ServoRequest::Reset, Mode::Unhomed | Mode::Homing) => return Ok(false),
            (ServoRequest::Reset, Mode::Holding(f) | Mode::SafeState(f)) => {
                return self.reset(f, queue, encoder_rad)
            }
        };
        if let Mode::Holding(_) = self.mode {
            // Disable while holding: torque off at once, the machine is at rest.
            self.enter_safe_state(fault, &mut scratch);
            return Ok(false);
        }
        self.latch(fault, &mut scratch);
        Ok(false)
    }

    /// `Reset` from `Holding(fault)` or `SafeState(fault)` (the module's table).
    fn reset(
        &mut self,
        fault: Fault,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
    ) -> Result<bool, ResetRefusal> {
        if fault.needs_reboot() {
            return Err(ResetRefusal::Permanent(fault));
        }
        if !self.homed() {
            let Mode::SafeState(_) = self.mode else {
                return Err(ResetRefusal::NotHomed);
            };
            // The zero is unknown: nothing engages. Back to where the boot left an incremental
            // machine (drives off, every setpoint refused), so Home may run.
            self.clear_motion(queue);
            self.mode = Mode::Unhomed;
            self.homing = None;
            return Ok(false);
        }
        let servo = self.servo.as_mut().ok_or(ResetRefusal::Permanent(fault))?;
        let tool_mm = self
            .active
            .engage(servo, encoder_rad)
            .map_err(ResetRefusal::Engage)?;
        let was_off = !self.drives_enabled();
        self.clear_motion(queue);
        self.mode = Mode::Running;
        self.motion = MotionState::at_rest(tool_mm);
        self.setpoint_mm = tool_mm;
        self.reference_rad = encoder_rad;
        self.encoders = EncoderCheck::new(encoder_rad, self.count_rad);
        Ok(was_off)
    }

    /// Drops what a reset leaves behind: the stop, the blend, the queued setpoints, the last
    /// torque.
    fn clear_motion(&mut self, queue: &mut Consumer<'_, MotionSetpoint<f32>>) {
        while queue.dequeue().is_some() {}
        self.stop = None;
        self.blend = None;
        self.last_torque_nm = [0.0; 2];
    }
}
