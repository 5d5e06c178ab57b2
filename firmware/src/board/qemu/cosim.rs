//! Co-simulation mode of the QEMU board (`firmware cosim` on the semihosting command line):
//! the production app drives host-sim's six-bar plant instead of the plant inside the firmware.
//!
//! Every servo sample, in [`Board::begin_sample`](super::super::Board::begin_sample), the board
//! writes the PWM duty registers, the drive-enable line and the host link's transmitted bytes
//! to the host and blocks until the host answers with the encoder counters after one period of
//! the plant under those torques, the index captures and the link's received bytes
//! (`cosim-wire` defines the bytes). The host is `host_sim::cosim`. Both calls are ARM
//! semihosting on named pipes: QEMU runs them on the vCPU's thread, so under `-icount` virtual
//! time stands still while the host computes, and the firmware sees the same hardware it sees in
//! the in-firmware plant's scenarios (counter registers, index capture, enable line, duty).
//!
//! What differs from the other QEMU runs, and nothing else:
//! * the settings ([`settings`]): incremental encoders with the counts, gear ratio and sign of
//!   the simulated machine's drives (the host sends them at boot, as a machine builder enters
//!   the encoders fitted), homing by index marks on the host's Home command (or at boot if the
//!   host asks), setpoints from the host link, no built-in tour;
//! * the encoder counters and index captures are written from the host's answer instead of the
//!   in-firmware plant; the test harness neither injects nor checks (the production path);
//! * the host link's port is the exchange ([`Port::Exchange`]) instead of UART0: its bytes
//!   travel inside the per-sample frames, so when a command arrives is part of the
//!   deterministic run.
//!
//! The host ends the run with a stop frame (drives off, QEMU exits 0). A host that goes away
//! (the pipe reaches its end) ends it too (exit 1), so QEMU never outlives its host.
use core::cell::RefCell;

use controller::encoder::{EncoderConfig, EncoderSign};
use controller::homing::HomingSettings;
use controller::settings::Settings;
use cortex_m_semihosting::syscall;
use cosim_wire::{
    decode_down, Config, Down, Hello, Sign, UpSample, DOWN_LEN, FROM_HOST_PIPE, MAX_LINK_BYTES,
    MAX_UP_LEN, TO_HOST_PIPE,
};
use critical_section::Mutex;
use heapless::Deque;

use super::{clock, hardware, semihosting, uart, PWM_MAX_DUTY};
use crate::link::LinkPort;

/// Whether the command line asks for co-simulation (`firmware cosim`).
pub fn requested() -> bool {
    let mut line = [0u8; 64];
    semihosting::command_line(&mut line)
        .split_whitespace()
        .nth(1)
        .is_some_and(|w| w == cosim_wire::COMMAND_WORD)
}

/// The exchange set up by [`settings`], for the board to take in `init`.
static EXCHANGE: Mutex<RefCell<Option<Exchange>>> = Mutex::new(RefCell::new(None));

/// Bytes the host link received, waiting for the link task (filled by the servo task).
static RX: Mutex<RefCell<Deque<u8, 1024>>> = Mutex::new(RefCell::new(Deque::new()));
/// Bytes the link task transmitted, waiting for the next sample's frame.
static TX: Mutex<RefCell<Deque<u8, 2048>>> = Mutex::new(RefCell::new(Deque::new()));

/// Opens the exchange, tells the host what the drives and homing expect and takes the board's
/// configuration from its answer: `production` with the machine's encoders, incremental
/// homing and the host link's motion.
pub fn settings(production: Settings) -> Settings {
    clock::start();
    let mut exchange = Exchange::open();
    let config = exchange.hello(&production);
    let encoders = [0, 1].map(|k| EncoderConfig {
        counts_per_rev: config.counts_per_rev[k],
        sign: match config.sign[k] {
            Sign::Normal => EncoderSign::Normal,
            Sign::Reversed => EncoderSign::Reversed,
        },
        gear_ratio: config.gear_ratio[k],
    });
    critical_section::with(|cs| *EXCHANGE.borrow_ref_mut(cs) = Some(exchange));
    Settings {
        link_motion: true,
        builtin_tour_mm: &[],
        encoders,
        homing: HomingSettings {
            absolute_encoders: false,
            at_boot: config.home_at_boot,
            ..production.homing
        },
        ..production
    }
}

/// The exchange [`settings`] opened (`None` outside co-simulation).
pub fn take() -> Option<Exchange> {
    critical_section::with(|cs| EXCHANGE.borrow_ref_mut(cs).take())
}

/// The two pipes and the frames in flight.
pub struct Exchange {
    to_host: usize,
    from_host: usize,
    /// The next sample's index.
    sample: u32,
    /// Link bytes the host accepts in the next frame.
    tx_budget: usize,
    /// The servo's longest step and overruns, as the last sample's status published them.
    worst_step_us: f32,
    overruns: u32,
    up: [u8; MAX_UP_LEN],
    down: [u8; DOWN_LEN],
}

/// Opens `name` in semihosting mode `mode` (1: "rb", 5: "wb"); a failure ends the run.
fn open(name: &str, mode: usize) -> usize {
    // QEMU reads the name up to its NUL, whatever the length says.
    let mut path = [0u8; 32];
    if name.len() >= path.len() {
        fail("pipe name too long");
    }
    path[..name.len()].copy_from_slice(name.as_bytes());
    // SAFETY: SYS_OPEN reads the NUL-terminated `path`, which lives across the call.
    let h = unsafe { syscall!(OPEN, path.as_ptr(), mode, name.len()) } as isize;
    if h < 0 {
        fail("cannot open the exchange's pipes (run it from host_sim::cosim)");
    }
    h as usize
}

/// The exchange failed: drives off, say why, end QEMU.
fn fail(why: &str) -> ! {
    hardware::safe_state();
    semihosting::console("FAIL cosim:");
    semihosting::console(why);
    semihosting::exit(false)
}

impl Exchange {
    fn open() -> Self {
        // The host opened its reading end first; this end, then the other (the host's order).
        let to_host = open(TO_HOST_PIPE, 5);
        let from_host = open(FROM_HOST_PIPE, 1);
        Exchange {
            to_host,
            from_host,
            sample: 0,
            tx_budget: 0,
            worst_step_us: 0.0,
            overruns: 0,
            up: [0; MAX_UP_LEN],
            down: [0; DOWN_LEN],
        }
    }

    fn write(&mut self, len: usize) {
        // SAFETY: SYS_WRITE reads `len` bytes of `self.up`, which lives across the call.
        let rest = unsafe { syscall!(WRITE, self.to_host, self.up.as_ptr(), len) };
        if rest != 0 {
            fail("the host stopped reading");
        }
    }

    /// Reads one whole down frame (a pipe may hand it over in parts).
    fn read(&mut self) -> Down<'_> {
        let mut got = 0;
        while got < DOWN_LEN {
            let want = DOWN_LEN - got;
            // SAFETY: SYS_READ writes at most `want` bytes from `got` on into `self.down`.
            let rest =
                unsafe { syscall!(READ, self.from_host, self.down[got..].as_mut_ptr(), want) };
            if rest >= want {
                fail("the host closed the exchange");
            }
            got += want - rest;
        }
        match decode_down(&self.down) {
            Ok(d) => d,
            Err(_) => fail("undecodable frame from the host"),
        }
    }

    fn hello(&mut self, settings: &Settings) -> Config {
        let hello = Hello {
            pwm_max_duty: PWM_MAX_DUTY,
            drive_full_scale_nm: settings.drive_full_scale_nm,
            index_rad: settings.homing.index_rad,
        };
        let Ok(n) = hello.encode(&mut self.up) else {
            fail("hello does not fit its buffer")
        };
        self.write(n);
        match self.read() {
            Down::Config(c) => {
                self.tx_budget = usize::from(c.tx_budget).min(MAX_LINK_BYTES);
                c
            }
            Down::Stop => stop(),
            Down::Sample(_) => fail("the host answered the hello with a sample"),
        }
    }

    /// One sample: the drives' registers and the link's bytes out, the counters, index
    /// captures and link bytes in. Pends the link task when bytes arrived.
    pub fn sample(&mut self) {
        let mut tx = [0u8; MAX_LINK_BYTES];
        let tx_len = critical_section::with(|cs| {
            let mut q = TX.borrow_ref_mut(cs);
            let n = q.len().min(self.tx_budget);
            for b in tx.iter_mut().take(n) {
                *b = q.pop_front().unwrap_or(0);
            }
            n
        });
        let up = UpSample {
            sample: self.sample,
            clock_ticks: clock::now_ticks(),
            duty: [hardware::pwm_duty(0), hardware::pwm_duty(1)],
            drive_enable: hardware::drive_enable(),
            worst_step_us: self.worst_step_us,
            overruns: self.overruns,
            tx: &tx[..tx_len],
        };
        let Ok(n) = up.encode(&mut self.up) else {
            fail("sample does not fit its buffer")
        };
        self.write(n);
        let expected = self.sample;
        let (budget, received) = match self.read() {
            Down::Sample(s) if s.sample == expected => {
                for k in 0..2 {
                    hardware::set_encoder_counts(k, s.counts[k]);
                    if let Some(c) = s.index_counts[k] {
                        hardware::index_pulse(k, c);
                    }
                }
                let received = !s.rx.is_empty();
                critical_section::with(|cs| {
                    let mut q = RX.borrow_ref_mut(cs);
                    for &b in s.rx {
                        // A full buffer drops the byte, as a UART's overrun would.
                        let _ = q.push_back(b);
                    }
                });
                (s.tx_budget, received)
            }
            Down::Sample(_) => fail("the host answered another sample"),
            Down::Stop => stop(),
            Down::Config(_) => fail("the host sent a configuration mid-run"),
        };
        self.tx_budget = usize::from(budget).min(MAX_LINK_BYTES);
        self.sample = self.sample.wrapping_add(1);
        if received {
            rtic::pend(crate::board::device::Interrupt::LINK_RX);
        }
    }
}

impl Exchange {
    /// End of a sample: keeps what the host is told of the servo's timing (the production
    /// status's own figures).
    pub fn note_status(&mut self, status: &controller::status::Status) {
        self.worst_step_us = status.worst_step_us;
        self.overruns = status.overruns;
    }
}

/// The host ends the run: drives off, QEMU exits with success.
fn stop() -> ! {
    hardware::safe_state();
    semihosting::exit(true)
}

/// The host link's byte port of the QEMU board: UART0, or the exchange in co-simulation.
pub enum Port {
    /// CMSDK UART0 on QEMU's first `-serial`.
    Uart(uart::CmsdkUart),
    /// The per-sample exchange's link bytes.
    Exchange {
        /// Bytes dropped because the transmit buffer was full.
        dropped: u32,
    },
}

impl LinkPort for Port {
    fn read_byte(&mut self) -> Option<u8> {
        match self {
            Port::Uart(u) => u.read_byte(),
            Port::Exchange { .. } => critical_section::with(|cs| RX.borrow_ref_mut(cs).pop_front()),
        }
    }

    fn write(&mut self, bytes: &[u8]) {
        match self {
            Port::Uart(u) => u.write(bytes),
            Port::Exchange { dropped } => critical_section::with(|cs| {
                let mut q = TX.borrow_ref_mut(cs);
                for &b in bytes {
                    if q.push_back(b).is_err() {
                        *dropped = dropped.wrapping_add(1);
                    }
                }
            }),
        }
    }
}
