#!/usr/bin/env bash
# Runs one firmware scenario under QEMU (MPS2-AN386, Cortex-M4F), bounded in time.
#   run-one.sh ELF SCENARIO WORKDIR [extra qemu args...]
# The firmware reads SCENARIO from the semihosting command line, prints PASS/FAIL on the
# console and exits through semihosting (0 = pass). defmt frames land in WORKDIR/defmt.bin.
# A watchdog reset reboots the machine inside the same run (QEMU's default watchdog action).
# -icount shift=3: every instruction advances virtual time by 8 ns (a 125 MHz core), so the
# 25 MHz timer and therefore the whole run are deterministic. Idle is a busy loop (see
# src/board/qemu.rs), which keeps the timer at its true rate with sleep=off.
set -u
elf=$(realpath "$1"); scenario=$2; workdir=$3; shift 3
mkdir -p "$workdir"
# The firmware appends its defmt frames (a boot after a watchdog reset adds to the first's).
rm -f "$workdir/defmt.bin"
cd "$workdir" && exec timeout --kill-after=5 "${QEMU_TIMEOUT_S:-30}" qemu-system-arm \
  -machine mps2-an386 -cpu cortex-m4 -nographic -monitor none -serial none \
  -icount shift=3,align=off,sleep=off \
  -semihosting-config enable=on,target=native,arg=firmware,arg="$scenario" \
  -kernel "$elf" "$@"
