//! Waiting for the machine to come to rest between the journey's steps (the controller
//! switches an uploaded calibration in at rest).

use crate::link::{ClientError, LinkClient};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// Waits until the controller's setpoint stops moving (`limit_s` of wall time at most); a
/// fault during the move is an error. Each status request is the wait (in co-simulation the
/// simulation advances until its answer comes).
pub fn wait_still<S: Read + Write>(
    client: &mut LinkClient<S>,
    limit_s: f64,
) -> Result<(), ClientError> {
    let start = Instant::now();
    loop {
        let s = client.status()?;
        if let Some(f) = s.fault {
            return Err(ClientError::Trajectory(format!(
                "the controller faulted during the move: {f:?}"
            )));
        }
        if !s.moving {
            return Ok(());
        }
        if start.elapsed().as_secs_f64() > limit_s {
            return Err(ClientError::Timeout(Duration::from_secs_f64(limit_s)));
        }
    }
}
