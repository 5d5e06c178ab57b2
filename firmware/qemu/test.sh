#!/usr/bin/env bash
# `cargo qemu-test` runner: runs every scenario of controller/src/scenario/mod.rs against the same
# firmware image and checks each one's exit code and console output (the harness prints PASS,
# or FAIL and why; the self-tests must print their own failure line, not just exit 1).
# Usage (cargo does this): test.sh path/to/firmware.elf
#
# The program and the calibration image are loaded separately, as they are flashed on the real
# board: the image bundled in the ELF's `.calibration` section is cut out into
# calibration.bin, the program is run without it, and QEMU's generic loader puts an image
# (valid, corrupted or none) at the CALIBRATION origin read from memory-qemu.x. So the
# firmware is shown to read whatever is in the region, not a copy linked into the program.
set -u
here=$(cd "$(dirname "$0")" && pwd)
elf=$1
out=${QEMU_TEST_OUT:-$(mktemp -d)}
cal=$(sed -n 's/^ *CALIBRATION *: *ORIGIN = \(0x[0-9A-Fa-f]*\).*/\1/p' "$here/../memory-qemu.x")
[ -n "$cal" ] || { echo "cannot find the CALIBRATION origin in memory-qemu.x"; exit 2; }
mkdir -p "$out"
python3 "$here/split-elf.py" "$elf" "$cal" "$out/program.elf" "$out/calibration.bin" || exit 2
# Corrupt: one node value (offset 200, inside the node table) replaced by 1.0f.
cp "$out/calibration.bin" "$out/corrupt.bin"
printf '\x00\x00\x80\x3f' | dd of="$out/corrupt.bin" bs=1 seek=200 conv=notrunc status=none
# Missing: erased flash (all 0xFF) over the whole 64 KiB region.
head -c 65536 /dev/zero | tr '\0' '\377' > "$out/erased.bin"
image() { echo "-device loader,file=$out/$1,addr=$cal"; }
elf_full=$elf
elf=$out/program.elf

passed=0; failed=0
# The console output a run must print, exactly (lines joined with spaces): a passing scenario
# only "PASS"; the self-tests their handler's line.
PASS='^PASS $'
PANIC='^FAIL panic: panicked at [^ ]+ self-test: panic path $'
HARDFAULT='^FAIL HardFault $'
# The stalled task: the watchdog's NMI reports, the machine resets, the boot after it passes.
WATCHDOG='^watchdog: torque off [0-9]+ us after the stall at [0-9]+ mm/s, [0-9]+ us after the last on-time step \(timeout [0-9]+ us\) PASS $'
# name  expected-exit  expected-console  scenario  extra-qemu-args
run() {
  local name=$1 expect=$2 console=$3 scenario=$4; shift 4
  local t0=$(date +%s%N) rc
  "$here/run-one.sh" "$elf" "$scenario" "$out/$name" "$@" > "$out/$name.log" 2>&1
  rc=$?
  local ms=$(( ($(date +%s%N) - t0) / 1000000 ))
  local dt=$((ms / 1000)).$(( (ms % 1000) / 100 ))
  if command -v defmt-print > /dev/null && [ -s "$out/$name/defmt.bin" ]; then
    defmt-print -e "$elf_full" --log-format '{L} {s}' < "$out/$name/defmt.bin" > "$out/$name.defmt.txt" 2>&1
  fi
  local joined
  joined=$(tr '\n' ' ' < "$out/$name.log")
  if [ "$rc" = "$expect" ] && printf '%s' "$joined" | grep -qE -- "$console"; then
    passed=$((passed + 1)); echo "ok   $name (exit $rc, ${dt}s): $joined"
  else
    failed=$((failed + 1)); echo "FAIL $name: exit $rc, expected $expect and console /$console/ (${dt}s)"; sed 's/^/    /' "$out/$name.log"
  fi
  if [ -f "$out/$name.defmt.txt" ]; then sed 's/^/    | /' "$out/$name.defmt.txt" | tail -n "${DEFMT_TAIL:-4}"; fi
}

run track          0 "$PASS" track        $(image calibration.bin)
run track-5g       0 "$PASS" track-5g     $(image calibration.bin)
# Faults of a moving machine, injected at the tour's top speed (1.38 m/s): categories 1 and 2
# (a controlled stop, then torque off / hold) ...
run nan-setpoint   0 "$PASS" nan-setpoint $(image calibration.bin)
run out-of-reach   0 "$PASS" out-of-reach $(image calibration.bin)
run jump           0 "$PASS" jump         $(image calibration.bin)
run underrun       0 "$PASS" underrun     $(image calibration.bin)
# ... and category 0 (torque off at once; the drives' dynamic braking must stop the machine
# inside the workspace): the controller and the encoders.
run overrun        0 "$PASS" overrun      $(image calibration.bin)
run encoder-frozen-at-rest 0 "$PASS" encoder-frozen-at-rest $(image calibration.bin)
run encoder-frozen-moving  0 "$PASS" encoder-frozen-moving  $(image calibration.bin)
run glitch-small   0 "$PASS" glitch-small $(image calibration.bin)
run glitch-large   0 "$PASS" glitch-large $(image calibration.bin)
# The servo task stalls (interrupts disabled) while the tool moves at speed: the watchdog removes
# torque within its timeout, then resets the machine; the boot after it keeps the drives off
# while the machine, which moves on through the reset, coasts within category 0's bounds.
run stalled-task   0 "$WATCHDOG" stalled-task $(image calibration.bin)
# Incremental encoders: the machine powers up at an unknown pose, homes on its index marks
# (speed and torque limited), then runs the tour with the grid applied; without joint 2's index
# mark the search ends at rest and the drives go off.
run homing         0 "$PASS" homing          $(image calibration.bin)
run homing-no-index 0 "$PASS" homing-no-index $(image calibration.bin)
# A calibration uploaded at run time into the inactive slot (the firmware's bundled second
# image), committed and switched to at rest; the same upload corrupted on the way is refused
# and the old image stays in force.
run calibration-upload         0 "$PASS" calibration-upload         $(image calibration.bin)
run calibration-upload-corrupt 0 "$PASS" calibration-upload-corrupt $(image calibration.bin)
run corrupt-image  0 "$PASS" bad-image-crc   $(image corrupt.bin)
run erased-image   0 "$PASS" bad-image-magic $(image erased.bin)
run no-image       0 "$PASS" bad-image-magic
# The production path (`run`, what the real board runs) past the old 6 s scenario limit.
run long-run       0 "$PASS" long-run     $(image calibration.bin)
# The failure paths themselves: a panic and a HardFault must end QEMU with exit 1 and their own
# line, not hang and not fail some other way.
run panic-exits      1 "$PANIC"     panic      $(image calibration.bin)
run hardfault-exits  1 "$HARDFAULT" hard-fault $(image calibration.bin)
# The bundled image alone (no loader) is the same valid image: the ELF runs standalone.
elf=$elf_full run bundled-image 0 "$PASS" track

command -v defmt-print > /dev/null || echo "(defmt-print not installed: defmt logs left undecoded in $out/*/defmt.bin)"
echo "qemu-test: $passed passed, $failed failed"
[ "$failed" = 0 ]
