/*
 * m4cycles: a QEMU TCG plugin that estimates Cortex-M4F cycles of measurement windows.
 * SPDX-License-Identifier: MIT OR Apache-2.0
 *
 * The benchmark firmware (firmware/src/bin/bench.rs) brackets each measured loop with
 * `mov r10, r10` (window start) and `mov r11, r11` (window end): no-ops the compiler never
 * emits. In a window every executed instruction is classified from its encoding (Thumb-2,
 * ARMv7E-M + FPv4-SP) and charged its Cortex-M4 cycle count; an instruction after which the
 * program counter is not the next address took a branch (B, BL, BX, CBZ, POP {pc}, ...) and
 * is charged the pipeline refill separately. At each window end one line goes to the file
 * given as `out=PATH`:
 *     W <instructions> <cycles without refills> <taken branches> <count per class...>
 * firmware/qemu/bench.sh turns windows into per-call figures.
 *
 * Timing table: ARM Cortex-M4 Technical Reference Manual (DDI 0439B, r0p1), chapter 3,
 * Table 3-1 "Cortex-M4 instruction set summary" with its load/store timing notes, and
 * chapter 7, Table 7-1 "FPU instruction set", for the FPU:
 *     ALU, move, compare, shift, bit-field, extend, IT, hints     1
 *     MUL, SMULL/UMULL/SMLAL/UMLAL, DSP multiplies                1
 *     MLA, MLS                                                    2
 *     SDIV, UDIV                                                  12 (2..12, early exit: upper bound)
 *     LDR/STR single (any size), VLDR/VSTR                        2, or 1 right after a load
 *                                                                   single (address/data phase
 *                                                                   pipelining)
 *     LDRD, STRD, VLDR/VSTR of a double                           3
 *     LDM/STM/PUSH/POP, VLDM/VSTM/VPUSH/VPOP                      1 + number of words
 *     VADD, VSUB, VMUL, VNMUL, VABS, VNEG, VCMP, VCVT, VMOV imm   1
 *     VMLA, VMLS, VNMLA, VNMLS, VFMA, VFMS, VFNMA, VFNMS          3
 *     VDIV.F32, VSQRT.F32                                         14
 *     VMOV core<->S, VMRS, VMSR                                   1 (2 for the 64-bit forms)
 *     taken branch / any write to PC: + P (pipeline refill, 1..3; bench.sh uses P = 2 and
 *                                                                   prints the range)
 * Assumptions: zero-wait-state memory (the G474 at 170 MHz has 4 flash wait states, partly
 * hidden by its ART accelerator), no stalls for register dependencies, IT never folded,
 * conditional instructions that fail their condition charged as if executed.
 *
 * The plugin API declarations below are written for this file from QEMU's documented plugin
 * API (version 1, as in QEMU 7.2; the functions are exported by qemu-system-arm). QEMU's own
 * header, qemu-plugin.h, is GPL-2.0-or-later and is deliberately not included or copied.
 *
 * Build: cc -shared -fPIC -O2 -o libm4cycles.so m4cycles.c
 * Self-test of the decoder: cc -DM4CYCLES_SELFTEST -O2 -o selftest m4cycles.c && ./selftest
 */
#include <stdint.h>
#include <stdio.h>
#include <string.h>

/* ---- The QEMU plugin API (version 1) as far as this plugin uses it. ---- */
typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
struct qemu_plugin_insn;
enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS };
int qemu_plugin_version __attribute__((visibility("default"))) = 1;
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
struct qemu_plugin_insn *qemu_plugin_tb_get_insn(const struct qemu_plugin_tb *tb, size_t idx);
const void *qemu_plugin_insn_data(const struct qemu_plugin_insn *insn);
size_t qemu_plugin_insn_size(const struct qemu_plugin_insn *insn);
uint64_t qemu_plugin_insn_vaddr(const struct qemu_plugin_insn *insn);
void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id,
                                           void (*cb)(qemu_plugin_id_t, struct qemu_plugin_tb *));
void qemu_plugin_register_vcpu_insn_exec_cb(struct qemu_plugin_insn *insn,
                                            void (*cb)(unsigned int vcpu, void *userdata),
                                            enum qemu_plugin_cb_flags flags, void *userdata);

/* ---- Instruction classes and their cycles. ---- */
enum cls { ALU, MUL, MAC, DIV, LD, ST, LDST2, LDSTM, BRANCH, VFP, VMAC, VDIV, VSQRT, VMOV,
           VLD, VST, VLDSTM, MARK_START, MARK_END, NCLS };
static const char *const names[NCLS] = { "alu", "mul", "mla", "div", "ld", "st", "ldrd", "ldm",
    "branch", "vfp", "vmla", "vdiv", "vsqrt", "vmov", "vldr", "vstr", "vldm", "mark", "mark" };

/* Class and cycles (without refill) of one instruction; `hw2` is ignored for 16-bit ones. */
static void classify(uint16_t hw1, uint16_t hw2, int wide, enum cls *c, unsigned *cycles)
{
    *cycles = 1;
    if (!wide) {
        if (hw1 == 0x46D2) { *c = MARK_START; return; }                 /* mov r10, r10 */
        if (hw1 == 0x46DB) { *c = MARK_END; return; }                   /* mov r11, r11 */
        if ((hw1 & 0xF800) == 0x4800 || (hw1 & 0xF000) == 0x5000 || (hw1 & 0xE000) == 0x6000 ||
            (hw1 & 0xF000) == 0x8000 || (hw1 & 0xF000) == 0x9000) {     /* LDR/STR single */
            int load = (hw1 & 0xF800) == 0x4800 || ((hw1 & 0xF000) == 0x5000 ? ((hw1 >> 9) & 7) >= 3 : (hw1 >> 11) & 1);
            *c = load ? LD : ST; *cycles = 2; return;
        }
        if ((hw1 & 0xF600) == 0xB400 || (hw1 & 0xF000) == 0xC000) {     /* PUSH/POP, STM/LDM */
            *c = LDSTM; *cycles = 1 + __builtin_popcount(hw1 & 0xFF) + ((hw1 & 0xF000) == 0xB000 && (hw1 & 0x100));
            return;
        }
        if ((hw1 & 0xFFC0) == 0x4340) { *c = MUL; return; }             /* MULS */
        if ((hw1 & 0xFF00) == 0x4700 || (hw1 & 0xF000) == 0xD000 || (hw1 & 0xF800) == 0xE000 ||
            (hw1 & 0xF500) == 0xB100) { *c = BRANCH; return; }          /* BX/BLX, B<c>, B, CBZ */
        *c = ALU; return;
    }
    if ((hw1 & 0xEC00) == 0xEC00 && (hw1 & 0x1000) == 0 && (hw2 & 0x0E00) == 0x0A00) {
        /* Floating point (coprocessors 10, 11). */
        if ((hw1 & 0xFE00) == 0xEC00) {                                  /* 1110 110x: memory */
            if ((hw1 & 0xFFE0) == 0xEC40) { *c = VMOV; *cycles = 2; return; }   /* 64-bit VMOV */
            if ((hw1 & 0xFF20) == 0xED00) { *c = (hw1 & 0x10) ? VLD : VST; *cycles = (hw2 & 0x100) ? 3 : 2; return; }
            *c = VLDSTM; *cycles = 1 + (hw2 & 0xFF); return;
        }
        if (hw2 & 0x10) { *c = VMOV; return; }                           /* VMOV core<->S, VMRS */
        switch ((hw1 >> 4) & 0xB) {                                      /* opc1 without D */
        case 0x0: case 0x1: case 0x9: case 0xA: *c = VMAC; *cycles = 3; return;
        case 0x8: *c = VDIV; *cycles = 14; return;
        case 0xB:
            if ((hw1 & 0xF) == 1 && ((hw2 >> 6) & 3) == 3) { *c = VSQRT; *cycles = 14; return; }
            *c = VFP; return;                                            /* VMOV, VABS, VNEG, VCMP, VCVT */
        default: *c = VFP; return;
        }
    }
    if ((hw1 & 0xFE40) == 0xE800) {                                      /* LDM/STM/PUSH/POP.W */
        *c = LDSTM; *cycles = 1 + __builtin_popcount(hw2 & 0xDFFF); return;
    }
    if ((hw1 & 0xFFF0) == 0xE8D0 && (hw2 & 0xFFE0) == 0xF000) { *c = BRANCH; *cycles = 2; return; } /* TBB/TBH */
    if ((hw1 & 0xFE40) == 0xE840) {                                      /* LDRD/STRD, LDREX/STREX */
        if (hw1 & 0x0120) { *c = LDST2; *cycles = 3; return; }
        *c = (hw1 & 0x10) ? LD : ST; *cycles = 2; return;
    }
    if ((hw1 & 0xFE00) == 0xF800) { *c = (hw1 & 0x10) ? LD : ST; *cycles = 2; return; }
    if ((hw1 & 0xFF80) == 0xFB00) {                                      /* MUL, MLA, MLS, DSP */
        int mla = ((hw1 >> 4) & 7) == 0 && ((hw2 >> 4) & 0xF) <= 1 && ((hw2 >> 12) != 0xF || ((hw2 >> 4) & 0xF) == 1);
        *c = mla ? MAC : MUL; *cycles = mla ? 2 : 1; return;
    }
    if ((hw1 & 0xFF80) == 0xFB80) {                                      /* long multiply, divide */
        if ((hw1 & 0xFFD0) == 0xFB90 && ((hw2 >> 4) & 0xF) == 0xF) { *c = DIV; *cycles = 12; return; }
        *c = MUL; return;
    }
    if ((hw1 & 0xF800) == 0xF000 && (hw2 & 0x8000) && ((hw2 & 0x5000) || (hw1 & 0x0380) != 0x0380)) {
        *c = BRANCH; return;                                             /* B.W, B<c>.W, BL */
    }
    *c = ALU;                                                            /* data processing, MSR, hints */
}

#ifndef M4CYCLES_SELFTEST
/* ---- Counting. ---- */
static FILE *out;
static int in_window;
static uint64_t count[NCLS], insns, base_cycles, taken;
static uint64_t next_pc = UINT64_MAX;   /* where the previous instruction falls through to */
static int prev_load;                   /* the previous instruction was a load single */

/* userdata: vaddr (bits 0-31) | size (32-35) | class (36-43) | cycles (44-51) */
static void exec(unsigned int vcpu, void *userdata)
{
    uint64_t u = (uintptr_t)userdata;
    uint64_t pc = u & 0xFFFFFFFFu;
    enum cls c = (enum cls)((u >> 36) & 0xFF);
    unsigned cycles = (u >> 44) & 0xFF;
    (void)vcpu;
    if (in_window) {
        if (pc != next_pc) taken++;
        if (prev_load && (c == LD || c == ST || c == VLD || c == VST)) cycles = 1;
        count[c]++; insns++; base_cycles += cycles;
    }
    if (c == MARK_START) {
        memset(count, 0, sizeof count); insns = base_cycles = taken = 0; in_window = 1;
    } else if (c == MARK_END && in_window) {
        in_window = 0;
        fprintf(out, "W %llu %llu %llu", (unsigned long long)insns, (unsigned long long)base_cycles, (unsigned long long)taken);
        for (int k = 0; k < MARK_START; k++) fprintf(out, " %llu", (unsigned long long)count[k]);
        fprintf(out, "\n"); fflush(out);
    }
    next_pc = pc + ((u >> 32) & 0xF);
    prev_load = c == LD || c == VLD;
}

static void translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    for (size_t i = 0; i < qemu_plugin_tb_n_insns(tb); i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        const uint8_t *b = qemu_plugin_insn_data(insn);
        /* The width from the encoding (first halfword 0b11101.., 0b1111...), not from
         * qemu_plugin_insn_size: QEMU 7.2 counts into a 16-bit instruction near the end of a
         * 1 KiB page the next halfword it peeked at. */
        size_t size = (b[1] >> 3) >= 0x1D ? 4 : 2;
        enum cls c; unsigned cycles;
        if (qemu_plugin_insn_size(insn) < size) continue;
        classify(b[0] | b[1] << 8, size == 4 ? (b[2] | b[3] << 8) : 0, size == 4, &c, &cycles);
        uint64_t u = (qemu_plugin_insn_vaddr(insn) & 0xFFFFFFFFu) | (uint64_t)size << 32 |
                     (uint64_t)c << 36 | (uint64_t)cycles << 44;
        qemu_plugin_register_vcpu_insn_exec_cb(insn, exec, QEMU_PLUGIN_CB_NO_REGS, (void *)(uintptr_t)u);
    }
}

__attribute__((visibility("default")))
int qemu_plugin_install(qemu_plugin_id_t id, const void *info, int argc, char **argv)
{
    (void)info;
    for (int i = 0; i < argc; i++)
        if (strncmp(argv[i], "out=", 4) == 0) out = fopen(argv[i] + 4, "w");
    if (!out) { fprintf(stderr, "m4cycles: give out=PATH (a writable file)\n"); return -1; }
    fprintf(out, "H instructions cycles taken");
    for (int k = 0; k < MARK_START; k++) fprintf(out, " %s", names[k]);
    fprintf(out, "\n"); fflush(out);
    qemu_plugin_register_vcpu_tb_trans_cb(id, translate);
    return 0;
}
#else
/* ---- Self-test: encodings as assembled by LLVM (llvm-mc -mcpu=cortex-m4 -show-encoding). ---- */
int main(void)
{
    static const struct { uint16_t hw1, hw2; int wide; enum cls c; unsigned cycles; const char *what; } t[] = {
        {0x46D2, 0, 0, MARK_START, 1, "mov r10, r10"}, {0x46DB, 0, 0, MARK_END, 1, "mov r11, r11"},
        {0xEEB1, 0x0AE0, 1, VSQRT, 14, "vsqrt.f32 s0, s1"}, {0xEEB1, 0x0A60, 1, VFP, 1, "vneg.f32 s0, s1"},
        {0xEE8E, 0x1A80, 1, VDIV, 14, "vdiv.f32 s2, s29, s0"}, {0xEE00, 0x0A81, 1, VMAC, 3, "vmla.f32"},
        {0xEEA0, 0x0A81, 1, VMAC, 3, "vfma.f32"}, {0xEE20, 0x0AC1, 1, VFP, 1, "vnmul.f32"},
        {0xEE30, 0x0AC1, 1, VFP, 1, "vsub.f32"}, {0xEEBD, 0x0AC0, 1, VFP, 1, "vcvt.s32.f32"},
        {0xEEB5, 0x0A40, 1, VFP, 1, "vcmp.f32 s0, #0"}, {0xEEB7, 0x0A00, 1, VFP, 1, "vmov.f32 s0, #1"},
        {0xEE10, 0x0A90, 1, VMOV, 1, "vmov r0, s1"}, {0xEE00, 0x0A90, 1, VMOV, 1, "vmov s1, r0"},
        {0xEC51, 0x0B10, 1, VMOV, 2, "vmov r0, r1, d0"}, {0xEEF1, 0xFA10, 1, VMOV, 1, "vmrs APSR_nzcv, fpscr"},
        {0xED90, 0x0A01, 1, VLD, 2, "vldr s0, [r0, #4]"}, {0xED80, 0x0A01, 1, VST, 2, "vstr s0, [r0, #4]"},
        {0xED2D, 0x8B10, 1, VLDSTM, 17, "vpush {d8-d15}"}, {0xECBD, 0x8B10, 1, VLDSTM, 17, "vpop {d8-d15}"},
        {0xECB0, 0x0A04, 1, VLDSTM, 5, "vldmia r0!, {s0-s3}"},
        {0xE9D2, 0x0100, 1, LDST2, 3, "ldrd r0, r1, [r2]"}, {0xE9C2, 0x0100, 1, LDST2, 3, "strd r0, r1, [r2]"},
        {0xF8D1, 0x03E8, 1, LD, 2, "ldr.w r0, [r1, #1000]"}, {0xF8C1, 0x03E8, 1, ST, 2, "str.w r0, [r1, #1000]"},
        {0xF9B1, 0x0064, 1, LD, 2, "ldrsh.w r0, [r1, #100]"},
        {0xFB01, 0x3002, 1, MAC, 2, "mla"}, {0xFB01, 0x3012, 1, MAC, 2, "mls"}, {0xFB01, 0xF002, 1, MUL, 1, "mul"},
        {0xFB82, 0x0103, 1, MUL, 1, "smull"}, {0xFB91, 0xF0F2, 1, DIV, 12, "sdiv"}, {0xFBB1, 0xF0F2, 1, DIV, 12, "udiv"},
        {0xE8D0, 0xF001, 1, BRANCH, 2, "tbb"}, {0xE8D0, 0xF011, 1, BRANCH, 2, "tbh"},
        {0xE92D, 0x4FF0, 1, LDSTM, 10, "push.w {r4-r11, lr}"}, {0xE8BD, 0x8FF0, 1, LDSTM, 10, "pop.w {r4-r11, pc}"},
        {0xF7FF, 0xFFFE, 1, BRANCH, 1, "bl"}, {0xF000, 0xB800, 1, BRANCH, 1, "b.w"}, {0xF040, 0x8000, 1, BRANCH, 1, "bne.w"},
        {0xF3AF, 0x8000, 1, ALU, 1, "nop.w"}, {0xF3BF, 0x8F4F, 1, ALU, 1, "dsb"}, {0xF04F, 0x0001, 1, ALU, 1, "mov.w r0, #1"},
        {0xEA4F, 0x0101, 1, ALU, 1, "mov.w r1, r1"}, {0xFA00, 0xF001, 1, ALU, 1, "lsl.w r0, r0, r1"},
        {0xB5F0, 0, 0, LDSTM, 6, "push {r4-r7, lr}"}, {0xBDF0, 0, 0, LDSTM, 6, "pop {r4-r7, pc}"},
        {0x6808, 0, 0, LD, 2, "ldr r0, [r1]"}, {0x6008, 0, 0, ST, 2, "str r0, [r1]"}, {0x4801, 0, 0, LD, 2, "ldr r0, [pc, #4]"},
        {0x5888, 0, 0, LD, 2, "ldr r0, [r1, r2]"}, {0x5088, 0, 0, ST, 2, "str r0, [r1, r2]"}, {0x9801, 0, 0, LD, 2, "ldr r0, [sp, #4]"},
        {0x8808, 0, 0, LD, 2, "ldrh r0, [r1]"}, {0xC803, 0, 0, LDSTM, 3, "ldm r0, {r0, r1}"},
        {0x4770, 0, 0, BRANCH, 1, "bx lr"}, {0xD1FE, 0, 0, BRANCH, 1, "bne"}, {0xE7FE, 0, 0, BRANCH, 1, "b"},
        {0xB108, 0, 0, BRANCH, 1, "cbz r0"}, {0xBF18, 0, 0, ALU, 1, "it ne"}, {0x4348, 0, 0, MUL, 1, "muls r0, r1"},
        {0x1840, 0, 0, ALU, 1, "adds r0, r0, r1"}, {0x4288, 0, 0, ALU, 1, "cmp r0, r1"},
        {0x4400, 0, 0, ALU, 1, "addne r0, r0"}, {0x5688, 0, 0, LD, 2, "ldrsb r0, [r1, r2]"},
        {0x5488, 0, 0, ST, 2, "strb r0, [r1, r2]"}, {0x7848, 0, 0, LD, 2, "ldrb r0, [r1, #1]"},
        {0x8048, 0, 0, ST, 2, "strh r0, [r1, #2]"}, {0x9001, 0, 0, ST, 2, "str r0, [sp, #4]"},
        {0xE851, 0x0F00, 1, LD, 2, "ldrex r0, [r1]"}, {0xF851, 0x0022, 1, LD, 2, "ldr.w r0, [r1, r2, lsl #2]"},
        {0xE9DD, 0x0102, 1, LDST2, 3, "ldrd r0, r1, [sp, #8]"}, {0xFB11, 0x3002, 1, MUL, 1, "smlabb"},
        {0xFBE2, 0x0103, 1, MUL, 1, "umlal"}, {0xF380, 0x8811, 1, ALU, 1, "msr basepri, r0"},
        {0xF3EF, 0x8011, 1, ALU, 1, "mrs r0, basepri"}, {0xEEB0, 0x0A60, 1, VFP, 1, "vmov.f32 s0, s1"},
        {0xEEB8, 0x0AC0, 1, VFP, 1, "vcvt.f32.s32"}, {0xECA0, 0x0A04, 1, VLDSTM, 5, "vstmia r0!, {s0-s3}"},
        {0xED90, 0x0B00, 1, VLD, 3, "vldr d0, [r0]"}, {0xF240, 0x40D2, 1, ALU, 1, "movw r0, #1234"},
        {0xF361, 0x001E, 1, ALU, 1, "bfi"}, {0xF3C0, 0x51C7, 1, ALU, 1, "ubfx"}, {0xF7FF, 0xD7FE, 1, BRANCH, 1, "bl (J1=0)"},
    };
    int bad = 0;
    for (size_t i = 0; i < sizeof t / sizeof t[0]; i++) {
        enum cls c; unsigned cycles;
        classify(t[i].hw1, t[i].hw2, t[i].wide, &c, &cycles);
        if (c != t[i].c || cycles != t[i].cycles) {
            printf("m4cycles self-test: %s classified %s/%u, expected %s/%u\n", t[i].what, names[c], cycles, names[t[i].c], t[i].cycles);
            bad = 1;
        }
    }
    if (!bad) printf("# m4cycles self-test: %zu encodings classified as expected\n", sizeof t / sizeof t[0]);
    return bad;
}
#endif
