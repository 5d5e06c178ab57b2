#!/usr/bin/env bash
# `cargo qemu-bench` runner: runs the benchmark firmware under QEMU with `-icount shift=0`
# (virtual time advances exactly 1 ns per instruction), bounded in time, with the
# cycle-estimating TCG plugin `plugin/m4cycles.c` (built here with the C compiler); prints
#   BENCH <name> <instructions per call> <estimated Cortex-M4 cycles per call>
# plus a comment line per figure (cycle range for a branch refill of 1..3 cycles, executed
# instructions per call by class), and fails if the firmware did not finish cleanly, if the
# plugin's windows do not reproduce the firmware's instruction counts, or if the IK or FK no
# longer executes VSQRT (the software sqrtf is back).
#
# The firmware measures each figure as (N calls - N empty iterations) / N with SysTick; the
# plugin sees the same two loops as windows (markers in bench.rs) and charges each executed
# instruction its cycles from the Cortex-M4 timing table in m4cycles.c.
set -u
here=$(cd "$(dirname "$0")" && pwd)
elf=$(realpath "$1")
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cc=${CC:-cc}
if ! "$cc" -std=c11 -Wall -Wextra -Werror -O2 -DM4CYCLES_SELFTEST -o "$out/selftest" "$here/plugin/m4cycles.c" \
    || ! "$out/selftest" \
    || ! "$cc" -std=c11 -Wall -Wextra -Werror -O2 -shared -fPIC -o "$out/libm4cycles.so" "$here/plugin/m4cycles.c"; then
  echo "qemu-bench: FAILED to build the cycle plugin with '$cc' (bash tests/run-all.sh installs gcc)"; exit 1
fi
(cd "$out" && timeout --kill-after=5 "${QEMU_TIMEOUT_S:-60}" qemu-system-arm \
  -machine mps2-an386 -cpu cortex-m4 -nographic -monitor none -serial none \
  -icount shift=0,align=off,sleep=off \
  -semihosting-config enable=on,target=native,arg=bench \
  -plugin "$out/libm4cycles.so,out=$out/windows.txt" \
  -kernel "$elf" >"$out/bench.txt")
rc=$?
n=$(grep -c '^BENCH ' "$out/bench.txt")
if [ "$rc" != 0 ] || [ "$n" -lt 4 ]; then
  cat "$out/bench.txt"; echo "qemu-bench: FAILED (exit $rc, $n figures)"; exit 1
fi
# Window 2k is the empty loop and 2k+1 the measured one of the k-th BENCH line; each figure is
# divided by the calls of the last '# calls per figure: N' line before it.
awk -v refill=2 '
  FNR == NR {
    if ($1 == "H") { for (i = 5; i <= NF; i++) cls[i] = $i; ncol = NF }
    if ($1 == "W") { w++; for (i = 2; i <= NF; i++) win[w, i] = $i }
    next
  }
  /^# calls per figure: / { calls = $5 }
  /^# instructions per counter tick: / { tick = $6 }
  $1 != "BENCH" { print; next }
  {
    k++; e = 2 * k - 1; b = 2 * k
    if (calls <= 0 || !((b, 2) in win)) { printf "qemu-bench: FAILED: no plugin window for %s\n", $2; bad = 1; exit }
    insns = (win[b, 2] - win[e, 2]) / calls
    base = (win[b, 3] - win[e, 3]) / calls
    taken = (win[b, 4] - win[e, 4]) / calls
    # SysTick counts whole ticks: each of the two loops (empty and measured) is exact to a
    # tick, so their difference over few calls is exact to two ticks per call only (where the
    # loops fall between ticks moves with the code layout).
    slack = 0.5 + 2 * tick / calls
    if (insns - $3 > slack || $3 - insns > slack) {
      printf "qemu-bench: FAILED: plugin window of %s has %.1f instructions per call, SysTick %s\n", $2, insns, $3; bad = 1; exit
    }
    printf "BENCH %s %s %.1f\n", $2, $3, base + refill * taken
    instr[$2] = $3; cycles[$2] = base + refill * taken
    line = sprintf("#   %s: %.1f..%.1f cycles for a branch refill of 1..3; per call:", $2, base + taken, base + 3 * taken)
    for (i = 5; i <= ncol; i++) {
      v = (win[b, i] - win[e, i]) / calls
      if (cls[i] == "vsqrt") vsqrt[$2] = v
      if (v >= 0.05) line = line sprintf(" %s %.1f", cls[i], v)
    }
    print line sprintf(", taken branches %.1f", taken)
  }
  END {
    if (bad) exit 1
    if (instr["sixbar_solve"] > 0 && instr["ik_f32"] > 0 && instr["fk_f32"] > 0) {
      printf "# sixbar_solve / ik_f32: %.0fx instructions, %.0fx cycles; sixbar_solve / fk_f32: %.0fx, %.0fx\n", \
        instr["sixbar_solve"] / instr["ik_f32"], cycles["sixbar_solve"] / cycles["ik_f32"], \
        instr["sixbar_solve"] / instr["fk_f32"], cycles["sixbar_solve"] / cycles["fk_f32"]
    }
    if (vsqrt["ik_f32"] < 2 || vsqrt["fk_f32"] < 1) {
      printf "qemu-bench: FAILED: VSQRT per call: ik_f32 %.1f (expected 2), fk_f32 %.1f (expected 1); the software sqrtf is back\n", vsqrt["ik_f32"], vsqrt["fk_f32"]; exit 1
    }
  }
' "$out/windows.txt" "$out/bench.txt" || { echo "qemu-bench: FAILED"; exit 1; }
