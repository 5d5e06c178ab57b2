#!/usr/bin/env bash
# `cargo qemu-test` runner: runs every scenario of src/scenario.rs against the same firmware
# image and checks each one's exit code. Usage (cargo does this): test.sh path/to/firmware.elf
#
# Fault injection of the calibration image happens here, from outside the firmware, the way a
# bad flash would: QEMU's generic loader writes into the CALIBRATION region after the ELF is
# loaded (the region's origin is read from memory-qemu.x).
set -u
here=$(cd "$(dirname "$0")" && pwd)
elf=$1
out=${QEMU_TEST_OUT:-$(mktemp -d)}
cal=$(sed -n 's/^ *CALIBRATION *: *ORIGIN = \(0x[0-9A-Fa-f]*\).*/\1/p' "$here/../memory-qemu.x")
[ -n "$cal" ] || { echo "cannot find the CALIBRATION origin in memory-qemu.x"; exit 2; }
# A word inside the node table (past the 72-byte header): a flipped calibration value.
corrupt=$(printf '0x%x' $((cal + 200)))

passed=0; failed=0
# name  expected-exit  scenario  extra-qemu-args
run() {
  local name=$1 expect=$2 scenario=$3; shift 3
  local t0=$(date +%s.%N) rc
  "$here/run-one.sh" "$elf" "$scenario" "$out/$name" "$@" > "$out/$name.log" 2>&1
  rc=$?
  local dt=$(printf '%.1f' "$(echo "$(date +%s.%N) - $t0" | bc)")
  if command -v defmt-print > /dev/null && [ -s "$out/$name/defmt.bin" ]; then
    defmt-print -e "$elf" --log-format '{L} {s}' < "$out/$name/defmt.bin" > "$out/$name.defmt.txt" 2>&1
  fi
  if [ "$rc" = "$expect" ]; then
    passed=$((passed + 1)); echo "ok   $name (exit $rc, ${dt}s): $(tr '\n' ' ' < "$out/$name.log")"
  else
    failed=$((failed + 1)); echo "FAIL $name: exit $rc, expected $expect (${dt}s)"; sed 's/^/    /' "$out/$name.log"
  fi
  if [ -f "$out/$name.defmt.txt" ]; then sed 's/^/    | /' "$out/$name.defmt.txt" | tail -n "${DEFMT_TAIL:-4}"; fi
}

run track          0 track
run nan-setpoint   0 nan-setpoint
run out-of-reach   0 out-of-reach
run jump           0 jump
run overrun        0 overrun
run corrupt-image  0 bad-image -device loader,addr="$corrupt",data=0x3f800000,data-len=4
run missing-image  0 bad-image -device loader,addr="$cal",data=0xffffffff,data-len=4
# The failure paths themselves: a panic and a HardFault must end QEMU with exit 1, not hang.
run panic-exits      1 panic
run hardfault-exits  1 hard-fault

command -v defmt-print > /dev/null || echo "(defmt-print not installed: defmt logs left undecoded in $out/*/defmt.bin)"
echo "qemu-test: $passed passed, $failed failed"
[ "$failed" = 0 ]
