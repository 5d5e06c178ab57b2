//! Ctrl-C while talking to a controller: the first one sets a flag the client's waits check
//! ([`requested`]), so that `host-sim link` can leave the controller as it found it (telemetry
//! off) before it exits with an error; a second one ends the process at once. The `ctrlc`
//! crate installs the handler (this crate has no unsafe code of its own).
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Once;

static REQUESTED: AtomicBool = AtomicBool::new(false);
static INSTALL: Once = Once::new();

/// Installs the handler (once per process; later calls do nothing).
pub fn install() {
    INSTALL.call_once(|| {
        // If the handler cannot be installed, Ctrl-C keeps its default action (the process ends
        // at once): nothing worse than before.
        let _ = ctrlc::set_handler(|| {
            if REQUESTED.swap(true, Ordering::SeqCst) {
                // The second Ctrl-C: the user does not want to wait for the clean-up.
                std::process::exit(130);
            }
        });
    });
}

/// Whether Ctrl-C was pressed (and its clean-up not yet done, [`clear`]).
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// Forgets a Ctrl-C once the clean-up it asked for has been done.
pub fn clear() {
    REQUESTED.store(false, Ordering::SeqCst);
}
