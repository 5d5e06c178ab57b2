//! Cross-crate integration tests (in `tests/tests/`):
//!
//! * `same_core_on_mcu`: the cases of `tests/golden/cases.rs` run on the Cortex-M4F (the
//!   firmware's `golden` binary under QEMU) and on the host must give bit-identical results:
//!   the firmware and the host tools really run the same core.
