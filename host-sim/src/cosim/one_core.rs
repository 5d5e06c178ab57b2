//! The co-simulation on one CPU: the thread that drives the exchange and QEMU (spawned while
//! the thread is pinned, so it inherits the pin) share one core.
//!
//! Why: the exchange is a ping-pong. Every 500 µs sample the host waits for QEMU's frame,
//! QEMU waits for the host's answer, and inside QEMU the vCPU thread and the main loop hand
//! the timer's interrupt to each other; at any moment one of them runs. Spread over cores,
//! each handoff is a wake-up on another core (an inter-processor interrupt, a core leaving
//! its idle state); on one core it is a context switch. A journey then takes half to two
//! thirds of the CPU time and wall time it takes spread (`cargo bench -p host-sim --bench cosim`
//! and `-- spread` compare them), and leaves the other cores free.
//! Nothing simulated depends on it: the exchange is the same, byte for byte.
//!
//! Which core: one no other co-simulation on this machine holds, the calling thread's own
//! first. A co-simulation claims its core with an advisory lock on a file in the temporary
//! directory (`host-sim-cosim-cpu<N>.lock`), released when it ends or its process dies. With
//! every core held, or where pinning is not possible (another OS, a restricted container),
//! nothing is pinned: the co-simulation runs as it would spread, only slower.
use std::fs::File;
use std::path::Path;

/// A thread pinned to one core for a co-simulation; dropping it gives the thread its former
/// cores back and releases the core's claim.
#[derive(Debug)]
pub struct OneCore {
    /// The core (as the OS numbers it).
    pub cpu: usize,
    #[cfg(target_os = "linux")]
    _restore: linux::Restore,
}

impl OneCore {
    /// Pins the calling thread to a core no other co-simulation holds (its own if free);
    /// `None` where none is free or pinning is not possible.
    pub fn pin() -> Option<OneCore> {
        Self::pin_claiming_in(&std::env::temp_dir())
    }

    /// [`OneCore::pin`] with the claims' lock files in `dir`.
    pub fn pin_claiming_in(dir: &Path) -> Option<OneCore> {
        #[cfg(target_os = "linux")]
        {
            let (cpu, restore) = linux::pin(dir)?;
            Some(OneCore {
                cpu,
                _restore: restore,
            })
        }
        #[cfg(not(target_os = "linux"))]
        {
            let _ = dir;
            None
        }
    }
}

#[cfg(target_os = "linux")]
mod linux {
    use super::{File, Path};
    use nix::fcntl::{flock, FlockArg};
    use nix::sched::{sched_getaffinity, sched_getcpu, sched_setaffinity, CpuSet};
    use nix::unistd::{gettid, Pid};
    use std::os::fd::AsRawFd;

    /// What dropping a pin undoes: the thread's former cores, the claim's lock (the file
    /// closes with it).
    #[derive(Debug)]
    pub struct Restore {
        thread: Pid,
        before: CpuSet,
        _claim: File,
    }

    impl Drop for Restore {
        fn drop(&mut self) {
            // The thread may have ended (its pin with it): nothing to undo then.
            let _ = sched_setaffinity(self.thread, &self.before);
        }
    }

    pub fn pin(dir: &Path) -> Option<(usize, Restore)> {
        let thread = gettid();
        let before = sched_getaffinity(thread).ok()?;
        let allowed: Vec<usize> = (0..CpuSet::count())
            .filter(|&c| before.is_set(c).unwrap_or(false))
            .collect();
        if allowed.len() < 2 {
            return None;
        }
        let own = sched_getcpu().ok().filter(|c| allowed.contains(c));
        let candidates = own
            .into_iter()
            .chain(allowed.iter().copied().filter(|&c| Some(c) != own));
        for cpu in candidates {
            let Some(claim) = claim(dir, cpu) else {
                continue;
            };
            let mut one = CpuSet::new();
            one.set(cpu).ok()?;
            sched_setaffinity(thread, &one).ok()?;
            return Some((
                cpu,
                Restore {
                    thread,
                    before,
                    _claim: claim,
                },
            ));
        }
        None
    }

    /// The lock file of `cpu`, locked by this call; `None` if another co-simulation holds it
    /// or it cannot be made.
    fn claim(dir: &Path, cpu: usize) -> Option<File> {
        let path = dir.join(format!("host-sim-cosim-cpu{cpu}.lock"));
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(path)
            .ok()?;
        flock(file.as_raw_fd(), FlockArg::LockExclusiveNonblock).ok()?;
        Some(file)
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;
    use nix::sched::{sched_getaffinity, CpuSet};
    use nix::unistd::Pid;

    fn cores(set: &CpuSet) -> Vec<usize> {
        (0..CpuSet::count())
            .filter(|&c| set.is_set(c).unwrap())
            .collect()
    }

    #[test]
    fn a_pin_holds_one_core_against_others_and_gives_it_back() {
        let claims = tempfile::tempdir().unwrap();
        let before = sched_getaffinity(Pid::from_raw(0)).unwrap();
        // Another co-simulation's thread, started before the pin (a thread started after
        // inherits it).
        let (go, wait) = std::sync::mpsc::channel::<()>();
        let dir = claims.path().to_path_buf();
        let other = std::thread::spawn(move || {
            wait.recv().unwrap();
            OneCore::pin_claiming_in(&dir).map(|p| p.cpu)
        });
        let first = OneCore::pin_claiming_in(claims.path());
        go.send(()).unwrap();
        let second = other.join().unwrap();
        let Some(first) = first else {
            assert!(
                cores(&before).len() < 2,
                "{:?} allowed, none pinned",
                cores(&before)
            );
            assert_eq!(second, None);
            return;
        };
        assert_eq!(
            cores(&sched_getaffinity(Pid::from_raw(0)).unwrap()),
            [first.cpu]
        );
        assert!(cores(&before).contains(&first.cpu));
        // The other co-simulation never takes the first one's core.
        if cores(&before).len() > 1 {
            let second = second.expect("a second core is free");
            assert_ne!(second, first.cpu);
            assert!(cores(&before).contains(&second));
        }
        drop(first);
        assert_eq!(sched_getaffinity(Pid::from_raw(0)).unwrap(), before);
    }

    #[test]
    fn a_thread_already_on_one_core_is_not_pinned() {
        let claims = tempfile::tempdir().unwrap();
        let allowed = cores(&sched_getaffinity(Pid::from_raw(0)).unwrap());
        let Some(first) = OneCore::pin_claiming_in(claims.path()) else {
            assert!(allowed.len() < 2, "{allowed:?} allowed, none pinned");
            return;
        };
        // The pinned thread asks again: it has one core, nothing to choose.
        assert!(OneCore::pin_claiming_in(claims.path()).is_none());
        drop(first);
    }
}
