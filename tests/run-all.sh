#!/usr/bin/env bash
# Runs every test of the project. On a fresh Debian machine it first installs what is missing:
# the thumbv7em-none-eabihf target (rustup), flip-link (cargo install, ~10 s; the STM32G474
# build links through it), QEMU and a C compiler for its cycle-estimating plugin (apt, when
# root or with sudo).
#
#   bash tests/run-all.sh
#
# Steps, each must pass:
#   0. formatting: cargo fmt --all --check; the documentation's links resolve
#   1. host tests of kinematics-core, the firmware's controller crate, host-sim and the
#      cross-crate tests (cargo test; the same-core test builds the firmware's golden binary and
#      runs it under QEMU), compiled by clippy with warnings denied: the host crates' clippy
#      (every target: host-sim's benches are compiled, not run); the commands reference page is
#      checked against the binary's --help
#   2. kinematics-core builds for the MCU (thumbv7em-none-eabihf, no_std)
#   3. firmware under QEMU: the real app against the in-firmware plant (cargo qemu-test)
#   4. firmware benchmarks under QEMU, printing BENCH <name> <instructions> <estimated cycles>
#      (cargo qemu-bench: builds the TCG plugin firmware/qemu/plugin/m4cycles.c with cc and
#      fails if the IK or FK executes no VSQRT)
#   5. the real board's firmware builds (cargo fw-build)
#   6. clippy, warnings denied, on the firmware for both boards (last, so that it reuses the
#      proc macros the release builds compiled)
#
# Every Cortex-M build (steps 2 to 5 and the firmware's clippy) goes to target/system-tests,
# where the host tests that run the firmware under QEMU (tests/support/firmware_build.rs) have
# just built it in release: the QEMU firmware is then built once, not once for the tests and
# again for `cargo qemu-test`, and the other firmware builds reuse its dependencies.
set -euo pipefail
cd "$(dirname "$0")/.."
mcu_target_dir=target/system-tests
# A fresh build gains nothing from incremental compilation's bookkeeping (about a fifth of the
# host crates' compile CPU); CI always builds from scratch.
export CARGO_INCREMENTAL=0
# Nor from the test build's line tables (the dev profile keeps them for backtraces while
# working): a failing test still names its file and line, and the host test build from scratch
# takes about 15 % less.
export CARGO_PROFILE_DEV_DEBUG=0
# And four codegen units instead of the dev profile's 256: on two cores the build is as
# parallel, does less work and inlines a little more.
export CARGO_PROFILE_DEV_CODEGEN_UNITS=4

# Each step's line carries the seconds since the start: where CI time goes.
step() { printf '\n=== [%4d s] %s\n' "$SECONDS" "$*"; }

step "setup: Rust target thumbv7em-none-eabihf"
if ! rustup target list --installed | grep -qx thumbv7em-none-eabihf; then
    rustup target add thumbv7em-none-eabihf
fi

step "setup: flip-link (the STM32G474 firmware's linker wrapper: stack overflow protection)"
if ! command -v flip-link >/dev/null 2>&1; then
    cargo install flip-link --version 0.1.12 --locked
fi

step "setup: qemu-system-arm, python3 (the QEMU runner splits the ELF with it), a C compiler (the bench's QEMU plugin)"
missing=""
command -v qemu-system-arm >/dev/null 2>&1 || missing="$missing qemu-system-arm"
command -v python3 >/dev/null 2>&1 || missing="$missing python3"
command -v cc >/dev/null 2>&1 || missing="$missing gcc libc6-dev"
if [ -n "$missing" ]; then
    if [ "$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
fi
qemu-system-arm --version | head -n 1

step "formatting (rustfmt.toml)"
cargo fmt --version >/dev/null 2>&1 || rustup component add rustfmt
cargo fmt --all --check

step "documentation links (every relative link and anchor in the Markdown files resolves)"
bash tests/check-doc-links.sh

# The host crates are compiled by clippy-driver, clippy's rustc (the workspace's crates only;
# dependencies by rustc): the test build is also their lint, warnings denied, where a separate
# `cargo clippy` would type-check the whole dependency tree again (about 40 s on two cores).
# `--all-targets --no-run` first compiles (and lints) every target `cargo clippy --all-targets`
# lints, host-sim's benches included; the run reuses it. The test binaries are then compiled as
# clippy compiles them, without rustc's MIR optimisations (LLVM's stay at the profile's level):
# the same results, and the integration tests take as long (about 170 s either way). The
# firmware builds the tests start (tests/support/firmware_build.rs) are plain release builds:
# cargo does not hand the wrapper to the processes it runs.
step "host tests, compiled through clippy (warnings denied)"
cargo clippy --version >/dev/null 2>&1 || rustup component add clippy
clippy_driver=$(rustup which clippy-driver 2>/dev/null || command -v clippy-driver) ||
    { echo "clippy-driver not found (rustup component add clippy)" >&2; exit 1; }
linted=(--config "build.rustc-workspace-wrapper=\"$clippy_driver\"" --config 'build.rustflags=["-Dwarnings"]')
cargo "${linted[@]}" test --locked --all-targets --no-run
cargo "${linted[@]}" test --locked

step "the commands reference is the binary's help (docs/reference/commands.md)"
HOST_SIM_BIN=target/debug/host-sim bash tests/gen-commands-doc.sh --check

step "kinematics-core for the MCU"
CARGO_TARGET_DIR=$mcu_target_dir cargo build --locked -p kinematics-core --target thumbv7em-none-eabihf --release

step "firmware under QEMU (real app, 2 kHz timer task, fault injection)"
CARGO_TARGET_DIR=$mcu_target_dir cargo qemu-test

step "firmware benchmarks under QEMU (instructions and estimated Cortex-M4 cycles per call; VSQRT executed)"
CARGO_TARGET_DIR=$mcu_target_dir cargo qemu-bench

step "firmware for the real board (STM32G474) builds"
CARGO_TARGET_DIR=$mcu_target_dir cargo fw-build

step "clippy: firmware, QEMU board and STM32G474 board"
CARGO_TARGET_DIR=$mcu_target_dir cargo clippy --locked --release -p firmware --target thumbv7em-none-eabihf --lib --bins -- -D warnings
CARGO_TARGET_DIR=$mcu_target_dir cargo clippy --locked --release -p firmware --target thumbv7em-none-eabihf --lib --bins \
    --no-default-features --features board-g474 -- -D warnings

step "all tests passed"
