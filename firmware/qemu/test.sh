#!/usr/bin/env bash
# `cargo qemu-test` runner: runs every scenario of controller/src/scenario/registry.rs against the same
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
  "$here/run-one.sh" "$elf" "$scenario" "$out/$name" "$@" < /dev/null > "$out/$name.log" 2>&1
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

# The runs come from the firmware's own registry of scenarios
# (controller/src/scenario/registry.rs): the command line `list` prints one line per run,
# `SCENARIO <test> <scenario> <exit> <console> <image>`.
listing=$("$here/run-one.sh" "$elf_full" list "$out/list" 2>&1) || { echo "FAIL list: the firmware did not list its scenarios"; echo "$listing"; exit 1; }
runs=$(printf '%s\n' "$listing" | grep '^SCENARIO ')
[ -n "$runs" ] || { echo "FAIL list: no scenario listed"; echo "$listing"; exit 1; }
while read -r _ test scenario expect console image; do
  case $console in
    pass) pattern=$PASS ;;
    panic) pattern=$PANIC ;;
    hard-fault) pattern=$HARDFAULT ;;
    watchdog) pattern=$WATCHDOG ;;
    *) echo "FAIL $test: unknown console expectation $console"; failed=$((failed + 1)); continue ;;
  esac
  case $image in
    valid) elf=$out/program.elf run "$test" "$expect" "$pattern" "$scenario" $(image calibration.bin) ;;
    corrupt) elf=$out/program.elf run "$test" "$expect" "$pattern" "$scenario" $(image corrupt.bin) ;;
    erased) elf=$out/program.elf run "$test" "$expect" "$pattern" "$scenario" $(image erased.bin) ;;
    none) elf=$out/program.elf run "$test" "$expect" "$pattern" "$scenario" ;;
    bundled) elf=$elf_full run "$test" "$expect" "$pattern" "$scenario" ;;
    *) echo "FAIL $test: unknown image $image"; failed=$((failed + 1)) ;;
  esac
done <<< "$runs"

command -v defmt-print > /dev/null || echo "(defmt-print not installed: defmt logs left undecoded in $out/*/defmt.bin)"
echo "qemu-test: $passed passed, $failed failed"
[ "$failed" = 0 ]
