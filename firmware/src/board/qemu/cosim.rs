//! Co-simulation mode of the QEMU board (`firmware cosim` on the semihosting command line):
//! the production app drives host-sim's six-bar plant instead of the plant inside the firmware.
//!
//! Every servo sample, in [`Board::begin_sample`](super::super::Board::begin_sample), the board
//! writes the PWM duty registers and the drive-enable line to the host and blocks until the
//! host answers with the encoder counters after one period of the plant under those torques,
//! the index captures and how many host-link bytes arrived (`cosim-wire` defines the bytes;
//! the host is `host_sim::cosim`). Both calls are ARM semihosting on named pipes: QEMU runs them
//! on the vCPU's thread, so under `-icount` virtual time stands still while the host computes,
//! and the firmware sees the hardware it sees in the in-firmware plant's scenarios (counter
//! registers, index capture, enable line, duty).
//!
//! What differs from the other QEMU runs, and nothing else:
//! * the settings ([`settings`]): incremental encoders with the counts, gear ratio and sign of
//!   the simulated machine's drives and the encoder angles of their index marks (the host sends
//!   them at boot, as a machine builder enters the encoders fitted and the marks measured in a
//!   jig), homing by index marks on the host's Home command (or at boot if the host asks),
//!   setpoints from the host link, no built-in tour;
//! * the encoder counters and index captures are written from the host's answer instead of the
//!   in-firmware plant; the test harness neither injects nor checks (the production path);
//! * the host link's port is the exchange ([`Port::Exchange`]) instead of UART0. Its bytes do
//!   not pass through the servo task: the port writes what the link task transmits to the host
//!   at once (a link frame between two samples) and reads what the host announced in a sample
//!   from a pipe of its own, as a UART driver reads its receive buffer. So the servo task's
//!   exchange costs the same few hundred instructions every sample (its measured step time
//!   stays the servo's) and when a command arrives is part of the deterministic run.
//!
//! The host ends the run with a stop frame (drives off, QEMU exits 0). A host that goes away
//! (the pipe reaches its end) ends it too (exit 1), so QEMU never outlives its host.
use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, AtomicUsize, Ordering};

use controller::encoder::{EncoderConfig, EncoderSign};
use controller::homing::HomingSettings;
use controller::settings::Settings;
use controller::status::Status;
use cortex_m_semihosting::syscall;
use cosim_wire::{
    decode_down, encode_link, Config, Down, Hello, Sign, UpSample, DOWN_LEN, FROM_HOST_PIPE,
    LINK_RX_PIPE, MAX_LINK_TX, MAX_UP_LEN, TO_HOST_PIPE, UP_HEADER_LEN,
};
use critical_section::Mutex;

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

/// Semihosting handles of the pipe to the host (servo task and link port write it, each frame
/// in one call) and of the link's receive pipe (the link port reads it).
static TO_HOST: AtomicUsize = AtomicUsize::new(0);
static LINK_RX: AtomicUsize = AtomicUsize::new(0);
/// Link bytes the host announced that the port has not read yet (the servo task adds, the
/// port subtracts).
static RX_AVAILABLE: AtomicU32 = AtomicU32::new(0);
/// Link bytes the port has read since boot (reported to the host every sample).
static RX_CONSUMED: AtomicU32 = AtomicU32::new(0);

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
            index_rad: config.index_rad,
            max_travel_rad: config.max_travel_rad,
            ..production.homing
        },
        ..production
    }
}

/// The exchange [`settings`] opened (`None` outside co-simulation).
pub fn take() -> Option<Exchange> {
    critical_section::with(|cs| EXCHANGE.borrow_ref_mut(cs).take())
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

/// Writes `bytes` to the host in one call (one frame: never interleaved with another).
fn write(bytes: &[u8]) {
    // SAFETY: SYS_WRITE reads `bytes.len()` bytes at the pointer; `bytes` lives across the call.
    let rest = unsafe {
        syscall!(
            WRITE,
            TO_HOST.load(Ordering::Relaxed),
            bytes.as_ptr(),
            bytes.len()
        )
    };
    if rest != 0 {
        fail("the host stopped reading");
    }
}

/// Fills `buf` from the pipe `handle` (a pipe may hand the bytes over in parts).
fn read(handle: usize, buf: &mut [u8]) {
    let mut got = 0;
    while got < buf.len() {
        let want = buf.len() - got;
        // SAFETY: SYS_READ writes at most `want` bytes from `got` on into `buf`.
        let rest = unsafe { syscall!(READ, handle, buf[got..].as_mut_ptr(), want) };
        if rest >= want {
            fail("the host closed the exchange");
        }
        got += want - rest;
    }
}

/// The exchange failed: drives off, say why, end QEMU.
fn fail(why: &str) -> ! {
    hardware::safe_state();
    semihosting::console("FAIL cosim:");
    semihosting::console(why);
    semihosting::exit(false)
}

/// The host ends the run: drives off, QEMU exits with success.
fn stop() -> ! {
    hardware::safe_state();
    semihosting::exit(true)
}

/// The servo task's side: one sample frame out, one answer in.
pub struct Exchange {
    from_host: usize,
    /// The next sample's index.
    sample: u32,
    /// The servo's longest step and overruns, as the last sample's status published them.
    worst_step_us: f32,
    overruns: u32,
    up: [u8; MAX_UP_LEN],
    down: [u8; DOWN_LEN],
}

impl Exchange {
    fn open() -> Self {
        // The host created the pipes and holds them open; the order does not matter.
        TO_HOST.store(open(TO_HOST_PIPE, 5), Ordering::Relaxed);
        let from_host = open(FROM_HOST_PIPE, 1);
        LINK_RX.store(open(LINK_RX_PIPE, 1), Ordering::Relaxed);
        RX_AVAILABLE.store(0, Ordering::Relaxed);
        RX_CONSUMED.store(0, Ordering::Relaxed);
        Exchange {
            from_host,
            sample: 0,
            worst_step_us: 0.0,
            overruns: 0,
            up: [0; MAX_UP_LEN],
            down: [0; DOWN_LEN],
        }
    }

    fn receive(&mut self) -> Down {
        read(self.from_host, &mut self.down);
        match decode_down(&self.down) {
            Ok(Down::Stop) => stop(),
            Ok(d) => d,
            Err(_) => fail("undecodable frame from the host"),
        }
    }

    fn hello(&mut self, settings: &Settings) -> Config {
        let hello = Hello {
            pwm_max_duty: PWM_MAX_DUTY,
            drive_full_scale_nm: settings.drive_full_scale_nm,
        };
        let Ok(n) = hello.encode(&mut self.up) else {
            fail("hello does not fit its buffer")
        };
        write(&self.up[..n]);
        match self.receive() {
            Down::Config(c) => c,
            _ => fail("the host answered the hello with something else"),
        }
    }

    /// One sample: the drives' registers out; the counters, index captures and the number of
    /// link bytes that arrived in. Pends the link task when bytes arrived.
    pub fn sample(&mut self) {
        let up = UpSample {
            sample: self.sample,
            clock_ticks: clock::now_ticks(),
            duty: [hardware::pwm_duty(0), hardware::pwm_duty(1)],
            drive_enable: hardware::drive_enable(),
            worst_step_us: self.worst_step_us,
            overruns: self.overruns,
            rx_consumed: RX_CONSUMED.load(Ordering::Relaxed),
        };
        let Ok(n) = up.encode(&mut self.up) else {
            fail("sample does not fit its buffer")
        };
        write(&self.up[..n]);
        let Down::Sample(s) = self.receive() else {
            fail("the host answered a sample with something else")
        };
        if s.sample != self.sample {
            fail("the host answered another sample");
        }
        for k in 0..2 {
            hardware::set_encoder_counts(k, s.counts[k]);
            if let Some(c) = s.index_counts[k] {
                hardware::index_pulse(k, c);
            }
        }
        self.sample = self.sample.wrapping_add(1);
        if s.rx_len > 0 {
            RX_AVAILABLE.fetch_add(u32::from(s.rx_len), Ordering::Relaxed);
            rtic::pend(crate::board::device::Interrupt::LINK_RX);
        }
    }

    /// End of a sample: keeps what the host is told of the servo's timing (the production
    /// status's own figures).
    pub fn note_status(&mut self, status: &Status) {
        self.worst_step_us = status.worst_step_us;
        self.overruns = status.overruns;
    }
}

/// The host link's byte port of the QEMU board: UART0, or the exchange in co-simulation.
// One instance, in the link task's static resource: the size difference costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Port {
    /// CMSDK UART0 on QEMU's first `-serial`.
    Uart(uart::CmsdkUart),
    /// The exchange's link pipes.
    Exchange(ExchangePort),
}

/// The link's bytes through the exchange: received bytes read from the host's pipe in blocks
/// of what the host announced, transmitted bytes sent in link frames.
pub struct ExchangePort {
    rx: [u8; 256],
    rx_len: usize,
    rx_at: usize,
    tx: [u8; UP_HEADER_LEN + MAX_LINK_TX],
}

impl ExchangePort {
    /// The port (the exchange must be open: [`settings`] ran).
    pub fn new() -> Self {
        ExchangePort {
            rx: [0; 256],
            rx_len: 0,
            rx_at: 0,
            tx: [0; UP_HEADER_LEN + MAX_LINK_TX],
        }
    }
}

impl Default for ExchangePort {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkPort for Port {
    fn read_byte(&mut self) -> Option<u8> {
        let p = match self {
            Port::Uart(u) => return u.read_byte(),
            Port::Exchange(p) => p,
        };
        if p.rx_at == p.rx_len {
            let available = RX_AVAILABLE.load(Ordering::Relaxed) as usize;
            let n = available.min(p.rx.len());
            if n == 0 {
                return None;
            }
            read(LINK_RX.load(Ordering::Relaxed), &mut p.rx[..n]);
            RX_AVAILABLE.fetch_sub(n as u32, Ordering::Relaxed);
            RX_CONSUMED.fetch_add(n as u32, Ordering::Relaxed);
            (p.rx_len, p.rx_at) = (n, 0);
        }
        p.rx_at += 1;
        Some(p.rx[p.rx_at - 1])
    }

    fn write(&mut self, bytes: &[u8]) {
        let p = match self {
            Port::Uart(u) => return u.write(bytes),
            Port::Exchange(p) => p,
        };
        for chunk in bytes.chunks(MAX_LINK_TX) {
            match encode_link(chunk, &mut p.tx) {
                Ok(n) => write(&p.tx[..n]),
                Err(_) => fail("link frame does not fit its buffer"),
            }
        }
    }
}
