//! QEMU for a co-simulation: the firmware ELF (found or built), the program without its bundled
//! calibration image, the image given loaded into the calibration region, the two pipes of the
//! exchange, and a process that never outlives its [`Qemu`].
//!
//! The pipes (frames to the host, frames from the host, the link's received bytes): the host
//! creates them (`mkfifo`) in a fresh working directory and opens each read-write, which never
//! blocks and keeps each pipe open on the host's side whatever QEMU does; the firmware opens
//! them at boot by name (semihosting `SYS_OPEN`, relative to QEMU's
//! working directory). A QEMU that dies is noticed while waiting for its next frame
//! ([`Qemu::read_up`] polls in slices and checks the process); a host that dies closes its
//! ends, the firmware's next read reaches the end of the pipe and the firmware ends QEMU.
//! Dropping a [`Qemu`] kills the process and waits for it (also on a panic's unwind).
use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use cosim_wire::{
    up_body_len, FROM_HOST_PIPE, LINK_RX_PIPE, MAX_UP_LEN, TO_HOST_PIPE, UP_HEADER_LEN,
};

use super::one_core::OneCore;
use super::CoSimError;

/// The calibration region's origin in the QEMU board's memory map (`firmware/memory-qemu.x`,
/// `CALIBRATION`; a test checks they agree).
pub const CALIBRATION_ORIGIN: u32 = 0x000F_0000;
/// The calibration region's length (bytes).
pub const CALIBRATION_LEN: usize = 64 * 1024;
/// QEMU's instruction counting, as `firmware/qemu/run-one.sh` runs every scenario: 8 ns of
/// virtual time per instruction (a 125 MHz core), virtual time independent of the host's.
pub const ICOUNT: &str = "shift=3,align=off,sleep=off";
/// The firmware's target and binary (`cargo build --release -p firmware --bin firmware
/// --target ...`).
const TARGET: &str = "thumbv7em-none-eabihf";

/// The workspace this host-sim was built in (where the firmware's sources are).
fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
}

/// The firmware ELF: `explicit`, else `HOST_SIM_FIRMWARE`, else the workspace's release build
/// (`target/thumbv7em-none-eabihf/release/firmware`, under `CARGO_TARGET_DIR` if set), built
/// with cargo if it is not there.
pub fn locate_firmware(explicit: Option<&Path>) -> Result<PathBuf, CoSimError> {
    let named = explicit
        .map(|p| (p.to_path_buf(), "--firmware"))
        .or_else(|| std::env::var_os("HOST_SIM_FIRMWARE").map(|p| (p.into(), "HOST_SIM_FIRMWARE")));
    if let Some((path, source)) = named {
        return if path.is_file() {
            Ok(path)
        } else {
            Err(CoSimError::Firmware(format!(
                "{source} names {}, which is not a file (build it with `cargo build --release -p \
                 firmware --bin firmware --target {TARGET}`)",
                path.display()
            )))
        };
    }
    let root = workspace_root();
    let target_dir = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target"));
    let elf = target_dir.join(TARGET).join("release").join("firmware");
    if elf.is_file() {
        return Ok(elf);
    }
    build_firmware(&root, &target_dir)?;
    if elf.is_file() {
        Ok(elf)
    } else {
        Err(CoSimError::Firmware(format!(
            "cargo built the firmware but {} is not there",
            elf.display()
        )))
    }
}

fn build_firmware(root: &Path, target_dir: &Path) -> Result<(), CoSimError> {
    if !root.join("firmware").join("Cargo.toml").is_file() {
        return Err(CoSimError::Firmware(format!(
            "no firmware ELF given and no firmware sources at {} to build it from: pass \
             --firmware FILE or set HOST_SIM_FIRMWARE",
            root.display()
        )));
    }
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(root)
        .env("CARGO_TARGET_DIR", target_dir)
        .args(["build", "--release", "-p", "firmware", "--bin", "firmware"])
        .args(["--target", TARGET])
        .stdout(Stdio::null())
        .status()
        .map_err(|e| {
            CoSimError::Firmware(format!("cannot run cargo to build the firmware: {e}"))
        })?;
    if status.success() {
        Ok(())
    } else {
        Err(CoSimError::Firmware(format!(
            "building the firmware failed ({status}); is the {TARGET} target installed? \
             (`rustup target add {TARGET}`; bash tests/run-all.sh installs it)"
        )))
    }
}

/// `elf` with its load segment at [`CALIBRATION_ORIGIN`] (the bundled image) turned into
/// `PT_NULL`, so QEMU loads the program only and the region holds what the co-simulation puts
/// there (as `firmware/qemu/split-elf.py` does for the scenarios). An ELF without that segment
/// is returned as it is.
pub fn program_without_image(elf: &[u8]) -> Result<Vec<u8>, CoSimError> {
    let bad = |why: &str| CoSimError::Firmware(format!("the firmware ELF: {why}"));
    if elf.len() < 52 || elf[..4] != *b"\x7fELF" || elf[4] != 1 || elf[5] != 1 {
        return Err(bad("not a 32-bit little-endian ELF"));
    }
    let u16_at = |at: usize| u16::from_le_bytes([elf[at], elf[at + 1]]);
    let u32_at = |at: usize| u32::from_le_bytes([elf[at], elf[at + 1], elf[at + 2], elf[at + 3]]);
    let (phoff, phentsize, phnum) = (u32_at(28) as usize, u16_at(42) as usize, u16_at(44));
    let mut out = elf.to_vec();
    for k in 0..usize::from(phnum) {
        let at = phoff + k * phentsize;
        if at + 20 > elf.len() {
            return Err(bad("program headers beyond the file"));
        }
        let (p_type, p_paddr, p_filesz) = (u32_at(at), u32_at(at + 12), u32_at(at + 16));
        if p_type == 1 && p_paddr == CALIBRATION_ORIGIN && p_filesz > 0 {
            out[at..at + 4].copy_from_slice(&0u32.to_le_bytes());
        }
    }
    Ok(out)
}

/// QEMU running the firmware in co-simulation, with the two pipes.
pub struct Qemu {
    child: Child,
    /// QEMU's working directory (pipes, program, image, console, `defmt.bin`).
    dir: tempfile::TempDir,
    to_host: File,
    from_host: File,
    /// The link's received bytes (non-blocking: the host never writes more than the pipe
    /// holds, and drains what a rebooted firmware left unread).
    link_rx: File,
    /// Bytes read from the firmware not yet handed out as a frame.
    pending: Vec<u8>,
    /// The core QEMU was started on, held while it runs (released after the kill in `drop`).
    core: Option<OneCore>,
}

impl Qemu {
    /// Starts `qemu` (the `qemu-system-arm` binary) on the program of `elf` with `image` in the
    /// calibration region (none if empty).
    pub fn spawn(qemu: &Path, elf: &Path, image: &[u8]) -> Result<Self, CoSimError> {
        if image.len() > CALIBRATION_LEN {
            return Err(CoSimError::Invalid(format!(
                "the calibration image is {} bytes, the region {CALIBRATION_LEN}",
                image.len()
            )));
        }
        let raw = std::fs::read(elf).map_err(|e| {
            CoSimError::Firmware(format!(
                "cannot read the firmware ELF {}: {e}",
                elf.display()
            ))
        })?;
        let dir = tempfile::Builder::new()
            .prefix("host-sim-cosim-")
            .tempdir()?;
        let program = dir.path().join("program.elf");
        std::fs::write(&program, program_without_image(&raw)?)?;
        for name in [TO_HOST_PIPE, FROM_HOST_PIPE, LINK_RX_PIPE] {
            nix::unistd::mkfifo(&dir.path().join(name), nix::sys::stat::Mode::S_IRWXU)
                .map_err(|e| CoSimError::Io(std::io::Error::from(e)))?;
        }
        // Read-write: opening never blocks (no peer needed) and the pipe stays open on this
        // side whatever QEMU does.
        let open = |name: &str| {
            OpenOptions::new()
                .read(true)
                .write(true)
                .open(dir.path().join(name))
        };
        let to_host = open(TO_HOST_PIPE)?;
        let from_host = open(FROM_HOST_PIPE)?;
        let link_rx = open(LINK_RX_PIPE)?;
        nix::fcntl::fcntl(
            link_rx.as_raw_fd(),
            nix::fcntl::FcntlArg::F_SETFL(nix::fcntl::OFlag::O_NONBLOCK),
        )
        .map_err(|e| CoSimError::Io(e.into()))?;
        let mut cmd = Command::new(qemu);
        cmd.current_dir(dir.path())
            .args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-nographic"])
            .args(["-monitor", "none", "-serial", "none", "-icount", ICOUNT])
            .args(["-semihosting-config"])
            .arg(format!(
                "enable=on,target=native,arg=firmware,arg={}",
                cosim_wire::COMMAND_WORD
            ))
            .arg("-kernel")
            .arg(&program);
        if !image.is_empty() {
            let path = dir.path().join("calibration.bin");
            std::fs::write(&path, image)?;
            cmd.arg("-device").arg(format!(
                "loader,file={},addr={CALIBRATION_ORIGIN:#x}",
                path.display()
            ));
        }
        let console = File::create(dir.path().join("console.txt"))?;
        cmd.stdin(Stdio::null())
            .stdout(console.try_clone()?)
            .stderr(console);
        let child = cmd.spawn().map_err(|e| {
            CoSimError::Qemu(format!(
                "cannot start {}: {e} (install qemu-system-arm: `apt-get install \
                 qemu-system-arm`, or name it with CoSimOptions::qemu)",
                qemu.display()
            ))
        })?;
        Ok(Qemu {
            child,
            dir,
            to_host,
            from_host,
            link_rx,
            pending: Vec::with_capacity(2 * MAX_UP_LEN),
            core: None,
        })
    }

    /// This QEMU with the core it was spawned on ([`OneCore`]: the spawning thread's pin,
    /// which QEMU inherited), held as long as QEMU runs.
    pub fn on_core(mut self, core: Option<OneCore>) -> Self {
        self.core = core;
        self
    }

    /// The core QEMU runs on, if pinned.
    pub fn core(&self) -> Option<usize> {
        self.core.as_ref().map(|c| c.cpu)
    }

    /// QEMU's working directory (the firmware's `defmt.bin` and console are there).
    pub fn dir(&self) -> &Path {
        self.dir.path()
    }

    /// What QEMU and the firmware printed (semihosting console, QEMU's errors).
    pub fn console(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("console.txt")).unwrap_or_default()
    }

    /// The next whole up frame into `frame` (header and body). Waits at most `timeout`; a
    /// QEMU that exits meanwhile is an error with its console.
    pub fn read_up(&mut self, frame: &mut Vec<u8>, timeout: Duration) -> Result<(), CoSimError> {
        let deadline = Instant::now() + timeout;
        loop {
            if self.pending.len() >= UP_HEADER_LEN {
                let body = up_body_len(&self.pending)
                    .map_err(|e| CoSimError::Protocol(format!("frame from the firmware: {e}")))?;
                let len = UP_HEADER_LEN + body;
                if self.pending.len() >= len {
                    frame.clear();
                    frame.extend_from_slice(&self.pending[..len]);
                    self.pending.drain(..len);
                    return Ok(());
                }
            }
            self.fill(deadline, timeout)?;
        }
    }

    /// Reads what the pipe has, waiting in slices of 50 ms (checking QEMU between them).
    fn fill(&mut self, deadline: Instant, timeout: Duration) -> Result<(), CoSimError> {
        use nix::poll::{poll, PollFd, PollFlags};
        loop {
            let mut fds = [PollFd::new(self.to_host.as_raw_fd(), PollFlags::POLLIN)];
            let ready = match poll(&mut fds, 50) {
                Ok(n) => n > 0,
                Err(nix::errno::Errno::EINTR) => false,
                Err(e) => return Err(CoSimError::Io(e.into())),
            };
            if ready {
                let mut buf = [0u8; 2 * MAX_UP_LEN];
                let n = self.to_host.read(&mut buf)?;
                self.pending.extend_from_slice(&buf[..n]);
                return Ok(());
            }
            if let Some(status) = self.child.try_wait()? {
                return Err(CoSimError::Exited {
                    status: status.to_string(),
                    console: self.console(),
                });
            }
            if Instant::now() > deadline {
                return Err(CoSimError::Timeout {
                    waited_s: timeout.as_secs_f64(),
                    console: self.console(),
                });
            }
        }
    }

    /// QEMU's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Closes the host's ends of both pipes, as a host that died would (QEMU is left running:
    /// the firmware must notice and end it). Later reads and writes fail.
    pub fn close_pipes(&mut self) -> Result<(), CoSimError> {
        self.to_host = File::open("/dev/null")?;
        self.from_host = OpenOptions::new().write(true).open("/dev/null")?;
        self.link_rx = OpenOptions::new().write(true).open("/dev/null")?;
        Ok(())
    }

    /// CPU time QEMU has used so far (s; Linux's `/proc`, `None` elsewhere).
    pub fn cpu_s(&self) -> Option<f64> {
        cpu_s_of(&format!("/proc/{}/stat", self.child.id()))
    }

    /// Writes one down frame.
    pub fn write_down(&mut self, frame: &[u8]) -> Result<(), CoSimError> {
        self.from_host.write_all(frame)?;
        Ok(())
    }

    /// Writes the link's received bytes (the caller keeps what is unread within the pipe's
    /// buffer).
    pub fn write_link_rx(&mut self, bytes: &[u8]) -> Result<(), CoSimError> {
        self.link_rx.write_all(bytes)?;
        Ok(())
    }

    /// Empties the link's receive pipe (bytes a firmware that rebooted did not read); returns
    /// how many there were.
    pub fn drain_link_rx(&mut self) -> Result<usize, CoSimError> {
        let mut n = 0;
        let mut buf = [0u8; 4096];
        loop {
            match self.link_rx.read(&mut buf) {
                Ok(0) => return Ok(n),
                Ok(k) => n += k,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(n),
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Waits up to `timeout` for QEMU to exit by itself (after a stop frame), killing it then.
    pub fn wait_exit(&mut self, timeout: Duration) -> Result<ExitStatus, CoSimError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(status) = self.child.try_wait()? {
                return Ok(status);
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                let _ = self.child.wait();
                return Err(CoSimError::Timeout {
                    waited_s: timeout.as_secs_f64(),
                    console: self.console(),
                });
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// User plus system CPU time of the process whose `/proc/PID/stat` is `path` (s), at the
/// usual 100 ticks per second.
pub fn cpu_s_of(path: &str) -> Option<f64> {
    let stat = std::fs::read_to_string(path).ok()?;
    // Fields after the command name (which may hold spaces), from field 3 on.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

impl Drop for Qemu {
    /// QEMU itself (not a wrapper script) is the child, so the kill reaches it.
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_calibration_region_is_the_firmwares() {
        let memory = include_str!("../../../firmware/memory-qemu.x");
        let line = memory
            .lines()
            .find(|l| l.trim_start().starts_with("CALIBRATION"))
            .expect("a CALIBRATION region");
        assert!(
            line.contains(&format!("ORIGIN = {CALIBRATION_ORIGIN:#010X}").replace("0X", "0x")),
            "{line}"
        );
        assert!(line.contains("LENGTH = 64K"), "{line}");
    }

    #[test]
    fn the_bundled_image_segment_is_nulled_and_nothing_else() {
        // A minimal ELF32 with two PT_LOAD program headers: the program and the image.
        let mut elf = vec![0u8; 52 + 2 * 32];
        elf[..6].copy_from_slice(b"\x7fELF\x01\x01");
        elf[28..32].copy_from_slice(&52u32.to_le_bytes());
        elf[42..44].copy_from_slice(&32u16.to_le_bytes());
        elf[44..46].copy_from_slice(&2u16.to_le_bytes());
        for (k, paddr) in [(0usize, 0u32), (1, CALIBRATION_ORIGIN)] {
            let at = 52 + 32 * k;
            elf[at..at + 4].copy_from_slice(&1u32.to_le_bytes());
            elf[at + 12..at + 16].copy_from_slice(&paddr.to_le_bytes());
            elf[at + 16..at + 20].copy_from_slice(&100u32.to_le_bytes());
        }
        let out = program_without_image(&elf).unwrap();
        assert_eq!(&out[52..56], &1u32.to_le_bytes(), "the program stays");
        assert_eq!(&out[84..88], &0u32.to_le_bytes(), "the image is PT_NULL");
        assert_eq!(out.len(), elf.len());
        assert!(program_without_image(b"not an elf").is_err());
    }
}
