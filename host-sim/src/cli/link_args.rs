//! `--tcp HOST:PORT | --serial PATH [--baud N]`: where the controller's link is, the flags
//! every command that talks to a controller has, checked and opened in one place.

use anyhow::{bail, Context, Result};
use host_sim::link::{LinkClient, Port, Transport};
use std::path::PathBuf;
use std::time::Duration;

/// The serial port's default rate: the STM32G474 firmware's.
pub const DEFAULT_BAUD: u32 = 115_200;

/// Longest wait `--timeout-s` may ask for (s): a day. Longer is a typo, and beyond ~1e19 s a
/// `Duration` cannot hold it.
pub const MAX_TIMEOUT_S: f64 = 86_400.0;

/// `--timeout-s` (how long to wait for each of the controller's replies) as a wait, checked the
/// same for every command that talks to a controller: seconds in (0, [`MAX_TIMEOUT_S`]];
/// anything else (NaN, zero, negative, more than a day) is an error naming the flag, never a
/// panic of `Duration`.
pub fn reply_timeout(timeout_s: f64) -> Result<Duration> {
    if !(timeout_s.is_finite() && timeout_s > 0.0 && timeout_s <= MAX_TIMEOUT_S) {
        bail!("--timeout-s must be a number of seconds in (0, {MAX_TIMEOUT_S}], not {timeout_s}");
    }
    Ok(Duration::from_secs_f64(timeout_s))
}

/// The controller's link. A command that needs exactly one of `--tcp` and `--serial` says so
/// with a clap `ArgGroup` over the ids `tcp` and `serial`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct LinkArgs {
    /// The controller's link on a TCP socket (QEMU): HOST:PORT.
    #[arg(long)]
    pub tcp: Option<String>,
    /// The controller's link on a serial port (the real board's ST-LINK virtual COM port, e.g.
    /// /dev/ttyACM0), 8 data bits, no parity, 1 stop bit, no flow control.
    #[arg(long)]
    pub serial: Option<PathBuf>,
    /// The serial port's baud rate (default 115200, the STM32G474 firmware's). Only with
    /// --serial.
    #[arg(long)]
    pub baud: Option<u32>,
}

impl LinkArgs {
    /// The transport the flags name (`None`: neither flag), or why they make none.
    pub fn transport(&self) -> Result<Option<Transport>> {
        match (&self.tcp, &self.serial) {
            (Some(_), Some(_)) => bail!("give either --tcp HOST:PORT or --serial PATH, not both"),
            (Some(_), None) if self.baud.is_some() => bail!("--baud applies to --serial only"),
            (Some(addr), None) => Ok(Some(Transport::Tcp(addr.clone()))),
            (None, Some(path)) => {
                let baud = self.baud.unwrap_or(DEFAULT_BAUD);
                if baud == 0 {
                    bail!("--baud must be a positive number of bits per second");
                }
                Ok(Some(Transport::Serial {
                    path: path.clone(),
                    baud,
                }))
            }
            (None, None) if self.baud.is_some() => bail!("--baud applies to --serial only"),
            (None, None) => Ok(None),
        }
    }

    /// Opens the link the flags name; the error says which and what to check.
    pub fn open(&self, timeout: Duration) -> Result<(Transport, LinkClient<Box<dyn Port>>)> {
        let Some(t) = self.transport()? else {
            bail!("give either --tcp HOST:PORT or --serial PATH");
        };
        let client = LinkClient::open(&t, timeout).with_context(|| match &t {
            Transport::Tcp(addr) => format!(
                "connecting to {addr}: is a controller listening there? (QEMU: \
                 docs/reference/link-protocol.md says how to start one)"
            ),
            Transport::Serial { path, baud } => {
                format!("opening the serial port {} at {baud} Bd", path.display())
            }
        })?;
        Ok((t, client))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reply_timeout_takes_seconds_up_to_a_day_and_refuses_the_rest() {
        assert_eq!(reply_timeout(5.0).unwrap(), Duration::from_secs(5));
        assert_eq!(
            reply_timeout(MAX_TIMEOUT_S).unwrap(),
            Duration::from_secs(86_400)
        );
        // 1e30 s would make `Duration::from_secs_f64` panic.
        for bad in [
            0.0,
            -1.0,
            f64::NAN,
            f64::INFINITY,
            MAX_TIMEOUT_S * 1.01,
            1e30,
        ] {
            let e = reply_timeout(bad).unwrap_err().to_string();
            assert!(e.contains("--timeout-s"), "{bad}: {e}");
        }
    }
}
