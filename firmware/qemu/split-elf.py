#!/usr/bin/env python3
"""Splits the QEMU firmware ELF into program and calibration image, as they are flashed.

    split-elf.py FIRMWARE.elf CAL_ORIGIN PROGRAM_OUT.elf CALIBRATION_OUT.bin

Writes the bytes of the load segment at CAL_ORIGIN (the bundled `.calibration` section) to
CALIBRATION_OUT.bin, and a copy of the ELF in which that segment is PT_NULL, so QEMU loads the
program only and the calibration region holds whatever the test puts there.
"""
import struct
import sys

elf_path, origin, program_out, image_out = sys.argv[1], int(sys.argv[2], 0), sys.argv[3], sys.argv[4]
elf = bytearray(open(elf_path, "rb").read())
assert elf[:4] == b"\x7fELF" and elf[4] == 1 and elf[5] == 1, "expected a 32-bit little-endian ELF"
e_phoff, = struct.unpack_from("<I", elf, 28)
e_phentsize, e_phnum = struct.unpack_from("<HH", elf, 42)
found = False
for k in range(e_phnum):
    at = e_phoff + k * e_phentsize
    p_type, p_offset, p_vaddr, p_paddr, p_filesz = struct.unpack_from("<IIIII", elf, at)
    if p_type == 1 and p_paddr == origin and p_filesz > 0:
        open(image_out, "wb").write(elf[p_offset:p_offset + p_filesz])
        struct.pack_into("<I", elf, at, 0)  # PT_NULL
        found = True
if not found:
    sys.exit(f"no load segment at {origin:#x} in {elf_path}")
open(program_out, "wb").write(elf)
