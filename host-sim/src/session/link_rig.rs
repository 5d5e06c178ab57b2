//! The session's rig over the controller's link: moves by `MoveTo`, the settle criterion on
//! the link's telemetry (the servo's own samples: reference, encoder, following error), the
//! instrument beside it. Works over any byte stream `link::LinkClient` takes (TCP to QEMU, the
//! board's serial port, the co-simulation's transport, whose waits advance the simulation).
//!
//! Machine time is the servo's sample count (`tick`) times the sample period: the same on a
//! real machine and in simulation, so the settle criterion and its timeout do not depend on how
//! fast the host or QEMU runs. Every wait also has a wall-clock bound (the link's timeout), so a
//! controller that stops answering is an error, not a hang.

use super::instrument::Instrument;
use super::{
    settled_at, Moved, PointRequest, Reading, Rig, ServoSample, SessionError, SettleCriterion,
    Settled,
};
use crate::link::link_protocol::{
    Command, HomingState, ModeCode, Response, StatusReport, TelemetrySample,
    MIN_TELEMETRY_DECIMATION,
};
use crate::link::{ClientError, LinkClient};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// The link's rig (module doc).
pub struct LinkRig<'a, S: Read + Write> {
    pub client: &'a mut LinkClient<S>,
    pub instrument: &'a mut dyn Instrument,
    /// The servo's sample period (s): the machine file's.
    pub sample_period_s: f64,
    /// Longest wall time for one move or settle (s).
    pub wall_timeout_s: f64,
    telemetry_on: bool,
    samples: Vec<ServoSample>,
}

impl<'a, S: Read + Write> LinkRig<'a, S> {
    /// A rig over `client` with `instrument`.
    pub fn new(
        client: &'a mut LinkClient<S>,
        instrument: &'a mut dyn Instrument,
        sample_period_s: f64,
    ) -> Self {
        LinkRig {
            client,
            instrument,
            sample_period_s,
            wall_timeout_s: 120.0,
            telemetry_on: false,
            samples: Vec::new(),
        }
    }

    fn sample(&self, t: &TelemetrySample) -> ServoSample {
        let f = |v: [f32; 2]| v.map(f64::from);
        ServoSample {
            t_s: f64::from(t.tick) * self.sample_period_s,
            reference_rad: f(t.reference_rad),
            encoder_rad: f(t.encoder_rad),
            following_error_rad: f64::from(t.following_error_rad),
        }
    }

    fn time(&self, s: &StatusReport) -> f64 {
        f64::from(s.ticks) * self.sample_period_s
    }
}

/// Why the controller cannot move, if it cannot.
pub fn not_ready(s: &StatusReport) -> Option<String> {
    if let Some(f) = s.fault {
        return Some(format!(
            "fault {f:?} latched (host-sim link reset, after removing its cause)"
        ));
    }
    if s.homing != HomingState::Homed {
        return Some(format!(
            "not homed ({:?}): home it first (host-sim link home)",
            s.homing
        ));
    }
    if s.mode != ModeCode::Running || !s.drives_enabled {
        return Some(format!(
            "mode {:?}, drives {}: it must be running with the drives on",
            s.mode,
            if s.drives_enabled { "on" } else { "off" }
        ));
    }
    None
}

impl<S: Read + Write> Rig for LinkRig<'_, S> {
    fn describe(&self) -> String {
        format!(
            "the controller over the link; {}",
            self.instrument.describe()
        )
    }

    fn check_ready(&mut self) -> Result<(), SessionError> {
        let s = self.client.status()?;
        match not_ready(&s) {
            Some(why) => Err(SessionError::NotReady(why)),
            None => Ok(()),
        }
    }

    fn move_to(&mut self, target_mm: [f64; 2]) -> Result<Moved, SessionError> {
        let duration_s = match self.client.request(Command::MoveTo {
            target_mm: target_mm.map(|v| v as f32),
        })? {
            Response::MovePlanned { duration_s } => f64::from(duration_s),
            _ => 0.0,
        };
        let start = Instant::now();
        let first = self.client.status()?;
        let (t0, mut last) = (self.time(&first), first);
        loop {
            if let Some(why) = last.fault.map(|f| format!("the controller faulted: {f:?}")) {
                return Err(SessionError::NotReady(why));
            }
            if !last.moving {
                return Ok(Moved {
                    t_s: self.time(&last),
                    encoder_rad: last.encoder_rad.map(f64::from),
                });
            }
            // Machine time: the planned duration and a margin; wall time: the rig's bound.
            if self.time(&last) - t0 > duration_s + 5.0
                || start.elapsed().as_secs_f64() > self.wall_timeout_s
            {
                return Err(SessionError::Link(ClientError::Timeout(
                    Duration::from_secs_f64(self.wall_timeout_s),
                )));
            }
            // The next status request is the wait: its round trip (in co-simulation, the
            // simulation advancing until the answer comes), so a run is the same every time.
            last = self.client.status()?;
        }
    }

    fn settle(&mut self, from_s: f64, c: &SettleCriterion) -> Result<Settled, SessionError> {
        if !self.telemetry_on {
            self.client.request(Command::Telemetry {
                decimation: MIN_TELEMETRY_DECIMATION,
            })?;
            self.telemetry_on = true;
        }
        self.samples.clear();
        let start = Instant::now();
        loop {
            // A status request advances time (the telemetry arriving meanwhile is kept) and
            // reports a fault at once.
            let s = self.client.status()?;
            if let Some(f) = s.fault {
                return Err(SessionError::NotReady(format!(
                    "the controller faulted: {f:?}"
                )));
            }
            let new: Vec<ServoSample> = self
                .client
                .take_telemetry()
                .iter()
                .map(|t| self.sample(t))
                .collect();
            self.samples.extend(new);
            if let Some(k) = settled_at(&self.samples, from_s, c) {
                let s = self.samples[k];
                let window = self
                    .samples
                    .iter()
                    .filter(|x| x.t_s >= s.t_s - c.dwell_s && x.t_s <= s.t_s)
                    .map(|x| x.following_error_rad)
                    .fold(0.0, f64::max);
                return Ok(Settled {
                    t_s: s.t_s,
                    settle_s: s.t_s - from_s,
                    reference_rad: s.reference_rad,
                    encoder_rad: s.encoder_rad,
                    following_error_rad: window,
                });
            }
            let last_t = self.samples.last().map_or(from_s, |x| x.t_s);
            if last_t - from_s > c.timeout_s {
                return Err(SessionError::NotSettled(*c));
            }
            if start.elapsed().as_secs_f64() > self.wall_timeout_s {
                return Err(SessionError::Link(ClientError::Timeout(
                    Duration::from_secs_f64(self.wall_timeout_s),
                )));
            }
        }
    }

    fn read(&mut self, point: &PointRequest) -> Result<Reading, SessionError> {
        self.instrument.read(point)
    }

    fn truth_mm(&self) -> Option<[f64; 2]> {
        self.instrument.last_truth_mm()
    }

    fn finish(&mut self) -> Result<(), SessionError> {
        if self.telemetry_on {
            self.client.request(Command::Telemetry { decimation: 0 })?;
            self.telemetry_on = false;
        }
        Ok(())
    }
}
