//! The co-simulation exchange: what the QEMU firmware in co-simulation mode and host-sim's plant
//! (`host_sim::cosim`) send each other, in lockstep with the 500 µs servo samples.
//!
//! Every servo sample the firmware's board writes one **sample** frame (the PWM duty registers
//! and the drive-enable line as the last sample left them) and then blocks reading one **down**
//! frame (the encoder counters after the plant has moved one period under those torques, index
//! captures, how many host-link bytes arrived). Both go through ARM semihosting (`SYS_WRITE`,
//! `SYS_READ`) on named pipes in QEMU's working directory; QEMU's virtual time stands still
//! while the core waits in the call (`-icount`), so the exchange costs the firmware no
//! simulated time beyond its own few instructions, and the run is deterministic
//! (docs/design/co-simulation.md).
//!
//! The host link's bytes do not pass through the servo task (which would pay for copying them):
//! * firmware to host: the link's port writes a **link** frame into [`TO_HOST_PIPE`] when the
//!   link task transmits, between two sample frames, so the host knows the period they were sent
//!   in;
//! * host to firmware: the host writes the bytes into [`LINK_RX_PIPE`] and announces their
//!   number in the sample's down frame ([`DownSample::rx_len`]); the link task reads them from
//!   there, as from a UART's receive buffer, and the firmware reports how many it has read
//!   ([`UpSample::rx_consumed`]).
//!
//! Byte layout, little-endian throughout:
//! * up frames ([`TO_HOST_PIPE`]): an 8-byte header (`tag`, body length `u16`, [`VERSION`]
//!   `u16`), then the body: [`Hello`] once per boot, [`UpSample`] every sample, link bytes;
//! * down frames ([`FROM_HOST_PIPE`]): always [`DOWN_LEN`] bytes (one read of a known length),
//!   tag first: [`Config`] in answer to a hello, [`DownSample`] to a sample, [`DOWN_STOP`] to end
//!   the run.
//!
//! Every sample carries its index (from 0 at each boot) both ways: the host refuses a sample
//! that is not the next one, the firmware a reply that is not for its sample, so a lost,
//! repeated or reordered sample ends the run instead of passing unnoticed.
#![no_std]
#![deny(missing_docs)]

/// Pipe the firmware writes (relative to QEMU's working directory).
pub const TO_HOST_PIPE: &str = "cosim-to-host";
/// Pipe the firmware's servo task reads.
pub const FROM_HOST_PIPE: &str = "cosim-from-host";
/// Pipe the firmware's host-link port reads (the link's received bytes).
pub const LINK_RX_PIPE: &str = "cosim-link-rx";
/// The word on the semihosting command line that selects co-simulation (`firmware cosim`).
pub const COMMAND_WORD: &str = "cosim";
/// Exchange format version, in every up frame's header and in [`Config`].
pub const VERSION: u16 = 3;

/// Host-link bytes the host sends per sample at most (16 Mbit/s at 2 kHz: the link is not the
/// bottleneck unless the host asks for a real UART's rate).
pub const MAX_LINK_RX_PER_SAMPLE: usize = 1024;
/// Host-link bytes the host may have sent that the firmware has not read yet (well inside a
/// pipe's buffer, so the host's write never waits).
pub const MAX_LINK_RX_OUTSTANDING: usize = 4096;
/// Longest link frame's body (the firmware's port writes at most this much in one frame).
pub const MAX_LINK_TX: usize = 256;
/// Header of an up frame: tag, body length, version.
pub const UP_HEADER_LEN: usize = 8;
/// Body of [`Hello`].
pub const HELLO_LEN: usize = 8;
/// Body of [`UpSample`].
pub const UP_SAMPLE_LEN: usize = 28;
/// Longest up frame.
pub const MAX_UP_LEN: usize = UP_HEADER_LEN + MAX_LINK_TX;
/// Every down frame's length.
pub const DOWN_LEN: usize = 48;

/// Up: the firmware booted (once per boot, before its first sample).
pub const TAG_HELLO: [u8; 4] = *b"HELO";
/// Up: one servo sample.
pub const TAG_SAMPLE: [u8; 4] = *b"SMPL";
/// Up: bytes the host link transmitted.
pub const TAG_LINK: [u8; 4] = *b"LINK";
/// Down: the board's configuration, in answer to [`TAG_HELLO`].
pub const TAG_CONFIG: [u8; 4] = *b"CONF";
/// Down: the plant after one sample, in answer to [`TAG_SAMPLE`].
pub const TAG_PLANT: [u8; 4] = *b"PLNT";
/// Down: end the run (the firmware puts the drives in the safe state and exits QEMU with 0).
pub const DOWN_STOP: [u8; 4] = *b"STOP";

/// Why bytes are not a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// Fewer bytes than the frame needs (or a buffer too small to encode into).
    Short,
    /// A tag this version does not know.
    Tag([u8; 4]),
    /// The other side speaks another version of the exchange.
    Version(u16),
    /// A length field beyond what a frame can hold.
    Length(usize),
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WireError::Short => f.write_str("frame shorter than its fields"),
            WireError::Tag(t) => write!(f, "unknown frame tag {t:?}"),
            WireError::Version(v) => {
                write!(f, "exchange version {v}, this side speaks {VERSION}")
            }
            WireError::Length(n) => write!(f, "length field {n} beyond the frame's capacity"),
        }
    }
}

fn put_u16(out: &mut [u8], at: usize, v: u16) {
    out[at..at + 2].copy_from_slice(&v.to_le_bytes());
}
fn put_u32(out: &mut [u8], at: usize, v: u32) {
    out[at..at + 4].copy_from_slice(&v.to_le_bytes());
}
fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}
fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}
fn tag_at(b: &[u8]) -> [u8; 4] {
    [b[0], b[1], b[2], b[3]]
}

fn header(out: &mut [u8], tag: [u8; 4], body_len: usize) {
    out[..4].copy_from_slice(&tag);
    put_u16(out, 4, body_len as u16);
    put_u16(out, 6, VERSION);
}

/// What the firmware tells the host at boot: how its drives' PWM maps to torque.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hello {
    /// PWM full-scale duty (the duty of +full scale torque; half of it is zero torque).
    pub pwm_max_duty: u16,
    /// The drives' torque at 0 % / 100 % duty (N·m), `Settings::drive_full_scale_nm`.
    pub drive_full_scale_nm: f32,
}

/// One sample, firmware to host.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UpSample {
    /// Samples since boot (0 for the first).
    pub sample: u32,
    /// The board's clock (25 MHz ticks since boot, wrapping) at the exchange: the host checks
    /// that consecutive samples are one period apart (none late).
    pub clock_ticks: u32,
    /// The PWM duty registers.
    pub duty: [u16; 2],
    /// The drive-enable line.
    pub drive_enable: bool,
    /// The servo's longest step so far (µs, `Status::worst_step_us`, the firmware's own
    /// measurement from its tick).
    pub worst_step_us: f32,
    /// The servo's deadline overruns so far (`Status::overruns`).
    pub overruns: u32,
    /// Link bytes the firmware has read from [`LINK_RX_PIPE`] since boot (wrapping).
    pub rx_consumed: u32,
}

/// An up frame, decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Up<'a> {
    /// The firmware booted.
    Hello(Hello),
    /// A sample.
    Sample(UpSample),
    /// Bytes the host link transmitted.
    Link(&'a [u8]),
}

impl Hello {
    /// Writes the frame into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, WireError> {
        let n = UP_HEADER_LEN + HELLO_LEN;
        let out = out.get_mut(..n).ok_or(WireError::Short)?;
        header(out, TAG_HELLO, HELLO_LEN);
        let b = UP_HEADER_LEN;
        put_u16(out, b, self.pwm_max_duty);
        put_u16(out, b + 2, 0);
        put_u32(out, b + 4, self.drive_full_scale_nm.to_bits());
        Ok(n)
    }
}

impl UpSample {
    /// Writes the frame into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, WireError> {
        let n = UP_HEADER_LEN + UP_SAMPLE_LEN;
        let out = out.get_mut(..n).ok_or(WireError::Short)?;
        header(out, TAG_SAMPLE, UP_SAMPLE_LEN);
        let b = UP_HEADER_LEN;
        put_u32(out, b, self.sample);
        put_u32(out, b + 4, self.clock_ticks);
        put_u16(out, b + 8, self.duty[0]);
        put_u16(out, b + 10, self.duty[1]);
        out[b + 12] = u8::from(self.drive_enable);
        out[b + 13] = 0;
        put_u16(out, b + 14, 0);
        put_u32(out, b + 16, self.worst_step_us.to_bits());
        put_u32(out, b + 20, self.overruns);
        put_u32(out, b + 24, self.rx_consumed);
        Ok(n)
    }
}

/// Writes a link frame carrying `bytes` (at most [`MAX_LINK_TX`]) into `out`; returns its
/// length.
pub fn encode_link(bytes: &[u8], out: &mut [u8]) -> Result<usize, WireError> {
    if bytes.is_empty() || bytes.len() > MAX_LINK_TX {
        return Err(WireError::Length(bytes.len()));
    }
    let n = UP_HEADER_LEN + bytes.len();
    let out = out.get_mut(..n).ok_or(WireError::Short)?;
    header(out, TAG_LINK, bytes.len());
    out[UP_HEADER_LEN..].copy_from_slice(bytes);
    Ok(n)
}

/// The length of the body an up frame's 8-byte `header` announces (the reader then reads that
/// many more bytes), after checking its tag and version.
pub fn up_body_len(header: &[u8]) -> Result<usize, WireError> {
    let header = header.get(..UP_HEADER_LEN).ok_or(WireError::Short)?;
    let version = u16_at(header, 6);
    if version != VERSION {
        return Err(WireError::Version(version));
    }
    let len = usize::from(u16_at(header, 4));
    let fits = match tag_at(header) {
        TAG_HELLO => len == HELLO_LEN,
        TAG_SAMPLE => len == UP_SAMPLE_LEN,
        TAG_LINK => (1..=MAX_LINK_TX).contains(&len),
        other => return Err(WireError::Tag(other)),
    };
    if fits {
        Ok(len)
    } else {
        Err(WireError::Length(len))
    }
}

/// Decodes a whole up frame (header and body).
pub fn decode_up(frame: &[u8]) -> Result<Up<'_>, WireError> {
    let len = up_body_len(frame)?;
    let body = frame
        .get(UP_HEADER_LEN..UP_HEADER_LEN + len)
        .ok_or(WireError::Short)?;
    Ok(match tag_at(frame) {
        TAG_HELLO => Up::Hello(Hello {
            pwm_max_duty: u16_at(body, 0),
            drive_full_scale_nm: f32_at(body, 4),
        }),
        TAG_SAMPLE => Up::Sample(UpSample {
            sample: u32_at(body, 0),
            clock_ticks: u32_at(body, 4),
            duty: [u16_at(body, 8), u16_at(body, 10)],
            drive_enable: body[12] != 0,
            worst_step_us: f32_at(body, 16),
            overruns: u32_at(body, 20),
            rx_consumed: u32_at(body, 24),
        }),
        _ => Up::Link(body),
    })
}

/// Counting direction of an encoder, as the firmware's `EncoderSign`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sign {
    /// Counts up when the joint angle increases.
    Normal,
    /// Counts down when the joint angle increases.
    Reversed,
}

/// The board's configuration from the host, in answer to [`Hello`]: the encoders fitted to the
/// simulated machine and where their index marks are (the settings a machine builder enters
/// for the motors fitted, the marks measured in a jig), and whether to home at boot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// Counts per motor revolution after quadrature decoding, per axis.
    pub counts_per_rev: [u32; 2],
    /// Motor revolutions per joint revolution, per axis.
    pub gear_ratio: [f32; 2],
    /// Counting direction, per axis.
    pub sign: [Sign; 2],
    /// Encoder angle of each axis's index mark (rad, `HomingSettings::index_rad`).
    pub index_rad: [f32; 2],
    /// Longest index search per axis (rad, `HomingSettings::max_travel_rad`).
    pub max_travel_rad: [f32; 2],
    /// Home at boot (`HomingSettings::at_boot`); otherwise the host link's Home starts it.
    pub home_at_boot: bool,
}

/// One sample, host to firmware: the encoder counters after the plant moved one period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DownSample {
    /// The sample this answers (the up frame's `sample`).
    pub sample: u32,
    /// The encoder counters (counts since power-on, as an incremental encoder's timer shows).
    pub counts: [i32; 2],
    /// Per axis, the counter's value at the index mark if the plant crossed it in this period.
    pub index_counts: [Option<i32>; 2],
    /// Host-link bytes the host wrote into [`LINK_RX_PIPE`] with this sample (at most
    /// [`MAX_LINK_RX_PER_SAMPLE`]).
    pub rx_len: u16,
}

/// A down frame, decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Down {
    /// The configuration (answer to a hello).
    Config(Config),
    /// A sample's answer.
    Sample(DownSample),
    /// End the run.
    Stop,
}

fn sign_byte(s: Sign) -> u8 {
    match s {
        Sign::Normal => 0,
        Sign::Reversed => 1,
    }
}

impl Down {
    /// Writes the frame into `out` (its first [`DOWN_LEN`] bytes, unused ones zero).
    pub fn encode(&self, out: &mut [u8]) -> Result<(), WireError> {
        let out = out.get_mut(..DOWN_LEN).ok_or(WireError::Short)?;
        out.fill(0);
        match self {
            Down::Stop => out[..4].copy_from_slice(&DOWN_STOP),
            Down::Config(c) => {
                out[..4].copy_from_slice(&TAG_CONFIG);
                put_u16(out, 4, VERSION);
                put_u16(out, 6, u16::from(c.home_at_boot));
                put_u32(out, 8, c.counts_per_rev[0]);
                put_u32(out, 12, c.counts_per_rev[1]);
                put_u32(out, 16, c.gear_ratio[0].to_bits());
                put_u32(out, 20, c.gear_ratio[1].to_bits());
                out[24] = sign_byte(c.sign[0]);
                out[25] = sign_byte(c.sign[1]);
                put_u32(out, 28, c.index_rad[0].to_bits());
                put_u32(out, 32, c.index_rad[1].to_bits());
                put_u32(out, 36, c.max_travel_rad[0].to_bits());
                put_u32(out, 40, c.max_travel_rad[1].to_bits());
            }
            Down::Sample(s) => {
                if usize::from(s.rx_len) > MAX_LINK_RX_PER_SAMPLE {
                    return Err(WireError::Length(usize::from(s.rx_len)));
                }
                out[..4].copy_from_slice(&TAG_PLANT);
                put_u32(out, 4, s.sample);
                put_u32(out, 8, s.counts[0] as u32);
                put_u32(out, 12, s.counts[1] as u32);
                let mut flags = 0u8;
                for k in 0..2 {
                    if let Some(c) = s.index_counts[k] {
                        flags |= 1 << k;
                        put_u32(out, 16 + 4 * k, c as u32);
                    }
                }
                out[24] = flags;
                put_u16(out, 26, s.rx_len);
            }
        }
        Ok(())
    }
}

/// Decodes a down frame (its first [`DOWN_LEN`] bytes).
pub fn decode_down(frame: &[u8]) -> Result<Down, WireError> {
    let b = frame.get(..DOWN_LEN).ok_or(WireError::Short)?;
    match tag_at(b) {
        DOWN_STOP => Ok(Down::Stop),
        TAG_CONFIG => {
            let version = u16_at(b, 4);
            if version != VERSION {
                return Err(WireError::Version(version));
            }
            let sign = |x: u8| if x == 0 { Sign::Normal } else { Sign::Reversed };
            Ok(Down::Config(Config {
                home_at_boot: u16_at(b, 6) & 1 != 0,
                counts_per_rev: [u32_at(b, 8), u32_at(b, 12)],
                gear_ratio: [f32_at(b, 16), f32_at(b, 20)],
                sign: [sign(b[24]), sign(b[25])],
                index_rad: [f32_at(b, 28), f32_at(b, 32)],
                max_travel_rad: [f32_at(b, 36), f32_at(b, 40)],
            }))
        }
        TAG_PLANT => {
            let rx_len = u16_at(b, 26);
            if usize::from(rx_len) > MAX_LINK_RX_PER_SAMPLE {
                return Err(WireError::Length(usize::from(rx_len)));
            }
            let flags = b[24];
            let index = |k: usize| (flags & (1 << k) != 0).then(|| u32_at(b, 16 + 4 * k) as i32);
            Ok(Down::Sample(DownSample {
                sample: u32_at(b, 4),
                counts: [u32_at(b, 8) as i32, u32_at(b, 12) as i32],
                index_counts: [index(0), index(1)],
                rx_len,
            }))
        }
        other => Err(WireError::Tag(other)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn up_frames_round_trip_and_announce_their_length() {
        let mut buf = [0u8; MAX_UP_LEN];
        let hello = Hello {
            pwm_max_duty: 4250,
            drive_full_scale_nm: 10.0,
        };
        let n = hello.encode(&mut buf).unwrap();
        assert_eq!(up_body_len(&buf[..UP_HEADER_LEN]), Ok(n - UP_HEADER_LEN));
        assert_eq!(decode_up(&buf[..n]), Ok(Up::Hello(hello)));

        let s = UpSample {
            sample: 7,
            clock_ticks: u32::MAX,
            duty: [0, 4250],
            drive_enable: true,
            worst_step_us: 123.5,
            overruns: 2,
            rx_consumed: 99,
        };
        let n = s.encode(&mut buf).unwrap();
        assert_eq!(n, UP_HEADER_LEN + UP_SAMPLE_LEN);
        assert_eq!(up_body_len(&buf), Ok(n - UP_HEADER_LEN));
        assert_eq!(decode_up(&buf[..n]), Ok(Up::Sample(s)));

        let bytes = [0u8, 1, 2, 0xff];
        let n = encode_link(&bytes, &mut buf).unwrap();
        assert_eq!(decode_up(&buf[..n]), Ok(Up::Link(&bytes[..])));
        // The longest link frame fits MAX_UP_LEN; an empty or longer one is refused.
        let full = [9u8; MAX_LINK_TX + 1];
        assert_eq!(encode_link(&full[..MAX_LINK_TX], &mut buf), Ok(MAX_UP_LEN));
        assert_eq!(
            encode_link(&full, &mut buf),
            Err(WireError::Length(MAX_LINK_TX + 1))
        );
        assert_eq!(encode_link(&[], &mut buf), Err(WireError::Length(0)));
    }

    #[test]
    fn a_wrong_tag_version_or_length_is_refused() {
        let mut buf = [0u8; MAX_UP_LEN];
        let n = UpSample {
            sample: 1,
            clock_ticks: 2,
            duty: [3, 4],
            drive_enable: false,
            worst_step_us: 0.0,
            overruns: 0,
            rx_consumed: 0,
        }
        .encode(&mut buf)
        .unwrap();
        let mut bad = buf;
        bad[6] = 9;
        assert_eq!(up_body_len(&bad), Err(WireError::Version(9)));
        let mut bad = buf;
        bad[..4].copy_from_slice(b"XXXX");
        assert_eq!(up_body_len(&bad), Err(WireError::Tag(*b"XXXX")));
        let mut bad = buf;
        bad[4] = 27;
        assert_eq!(up_body_len(&bad), Err(WireError::Length(27)));
        let mut bad = buf;
        bad[..4].copy_from_slice(&TAG_LINK);
        bad[4..6].copy_from_slice(&(MAX_LINK_TX as u16 + 1).to_le_bytes());
        assert_eq!(up_body_len(&bad), Err(WireError::Length(MAX_LINK_TX + 1)));
        assert_eq!(decode_up(&buf[..n - 1]), Err(WireError::Short));
    }

    #[test]
    fn down_frames_round_trip_at_their_fixed_length() {
        let mut buf = [0xaau8; DOWN_LEN];
        let config = Config {
            counts_per_rev: [1 << 20, 1 << 22],
            gear_ratio: [10.0, 1.0],
            sign: [Sign::Normal, Sign::Reversed],
            index_rad: [1.4, -1.4],
            max_travel_rad: [1.35, 1.25],
            home_at_boot: true,
        };
        Down::Config(config).encode(&mut buf).unwrap();
        assert_eq!(decode_down(&buf), Ok(Down::Config(config)));

        let s = DownSample {
            sample: 99,
            counts: [-5, i32::MAX],
            index_counts: [None, Some(-1_000_000)],
            rx_len: 3,
        };
        Down::Sample(s).encode(&mut buf).unwrap();
        assert_eq!(decode_down(&buf), Ok(Down::Sample(s)));
        Down::Stop.encode(&mut buf).unwrap();
        assert_eq!(decode_down(&buf), Ok(Down::Stop));

        assert_eq!(decode_down(&buf[..DOWN_LEN - 1]), Err(WireError::Short));
        let too_many = DownSample {
            rx_len: MAX_LINK_RX_PER_SAMPLE as u16 + 1,
            ..s
        };
        let n = MAX_LINK_RX_PER_SAMPLE + 1;
        assert_eq!(
            Down::Sample(too_many).encode(&mut buf),
            Err(WireError::Length(n))
        );
        let mut bad = [0u8; DOWN_LEN];
        Down::Sample(s).encode(&mut bad).unwrap();
        bad[26..28].copy_from_slice(&(n as u16).to_le_bytes());
        assert_eq!(decode_down(&bad), Err(WireError::Length(n)));
        bad[..4].copy_from_slice(b"PLNX");
        assert_eq!(decode_down(&bad), Err(WireError::Tag(*b"PLNX")));
    }
}
