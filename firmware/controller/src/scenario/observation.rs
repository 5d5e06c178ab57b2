//! What the harness sees of a sample ([`Observation`], the plant's true [`PlantState`]) and the
//! two checks every scenario's verdict is built from: a condition with its reason
//! ([`require`]) and the hardware's safe state ([`safe_state`]).
use crate::status::Status;

/// What the harness sees at the end of a sample.
#[derive(Clone, Copy, Debug)]
pub struct Observation<'s> {
    /// The status the servo task published in this sample.
    pub status: &'s Status,
    /// The drive-enable line, as the (simulated) hardware holds it.
    pub drive_enable: bool,
    /// Whether the drive-enable line was ever high since power-on (a sticky probe on the line).
    pub drive_enable_ever: bool,
    /// The torque the PWM duty registers command (N·m), decoded from the duty.
    pub drive_torque_nm: [f32; 2],
    /// The simulated plant's true joint state (not the encoders).
    pub plant: PlantState,
}

/// The simulated plant's true state, as the harness reads it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PlantState {
    /// Joint angles (rad), unquantised.
    pub joint_rad: [f32; 2],
    /// Joint speeds (rad/s).
    pub joint_rad_s: [f32; 2],
}

/// `Ok` when `ok`, else the reason `why`: the unit every check is made of.
pub(super) fn require(ok: bool, why: &'static str) -> Result<(), &'static str> {
    if ok {
        Ok(())
    } else {
        Err(why)
    }
}

/// The hardware shows the safe state: drive enable off, zero torque.
pub(super) fn safe_state(o: &Observation<'_>) -> Result<(), &'static str> {
    require(!o.drive_enable, "drive enable still on after the fault")?;
    require(
        o.drive_torque_nm == [0.0; 2],
        "torque commanded after the fault",
    )
}
