#!/usr/bin/env bash
# `cargo qemu-bench` runner: runs the benchmark firmware under QEMU with `-icount shift=0`
# (virtual time advances exactly 1 ns per instruction), bounded in time; prints its
# `BENCH <name> <instructions per call>` lines and fails if it did not finish cleanly.
set -u
elf=$(realpath "$1")
out=$(mktemp -d)
cd "$out" && timeout --kill-after=5 "${QEMU_TIMEOUT_S:-60}" qemu-system-arm \
  -machine mps2-an386 -cpu cortex-m4 -nographic -monitor none -serial none \
  -icount shift=0,align=off,sleep=off \
  -semihosting-config enable=on,target=native,arg=bench \
  -kernel "$elf" | tee "$out/bench.txt"
rc=${PIPESTATUS[0]}
n=$(grep -c '^BENCH ' "$out/bench.txt")
if [ "$rc" != 0 ] || [ "$n" -lt 4 ]; then echo "qemu-bench: FAILED (exit $rc, $n figures)"; exit 1; fi
