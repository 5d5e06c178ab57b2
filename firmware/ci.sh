#!/usr/bin/env bash
# What CI runs for the firmware. Call from the workspace root: `bash firmware/ci.sh`.
# Installs what is missing (qemu-system-arm from Debian, the Cortex-M4F target), then runs the
# QEMU scenarios, the benchmark and the real board's build. probe-rs is not needed here.
# Set FIRMWARE_DEFMT_PRINT=1 to also install defmt-print (about 4 minutes) so that the test
# output shows each scenario's decoded defmt log; without it the logs stay in defmt.bin files.
set -euo pipefail
if ! command -v qemu-system-arm > /dev/null; then
  apt-get update -qq && apt-get install -y -qq --no-install-recommends qemu-system-arm
fi
rustup target add thumbv7em-none-eabihf
if [ "${FIRMWARE_DEFMT_PRINT:-0}" = 1 ] && ! command -v defmt-print > /dev/null; then
  cargo install defmt-print --version 1.2.0 --locked
fi
cargo qemu-test
cargo qemu-bench
cargo fw-build
