//! The host link over the co-simulation: a byte stream for [`crate::link::LinkClient`] whose
//! writes go into the next samples' frames and whose reads run the simulation until the
//! controller has sent something.
//!
//! A read returns as soon as at least one byte came from the controller, after as many samples
//! as that took; with nothing after [`CoSimLink`]'s limit of simulated time it reports
//! `TimedOut`, which the client treats as a serial port's timeout (it asks again until its own
//! wall-clock timeout). So a request's answer arrives at the same sample in every run, and the
//! client never sleeps.
use std::io::{self, Read, Write};
use std::sync::{Arc, Mutex};

use super::exchange::Engine;
use super::lock;

/// The link's byte stream through the co-simulation (`CoSim::link`).
pub struct CoSimLink {
    engine: Arc<Mutex<Engine>>,
    /// Samples a read runs at most before it reports a timeout.
    read_limit_samples: u64,
}

impl CoSimLink {
    pub(super) fn new(engine: Arc<Mutex<Engine>>, read_limit_samples: u64) -> Self {
        CoSimLink {
            engine,
            read_limit_samples: read_limit_samples.max(1),
        }
    }
}

impl Read for CoSimLink {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if buf.is_empty() {
            return Ok(0);
        }
        let mut e = lock(&self.engine);
        let mut ran = 0;
        while e.from_firmware.is_empty() {
            if ran == self.read_limit_samples {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "no byte from the controller within the co-simulation's read limit",
                ));
            }
            e.step().map_err(io::Error::other)?;
            ran += 1;
        }
        let n = buf.len().min(e.from_firmware.len());
        for (slot, byte) in buf.iter_mut().zip(e.from_firmware.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }
}

impl Write for CoSimLink {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        lock(&self.engine).to_firmware.extend(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}
