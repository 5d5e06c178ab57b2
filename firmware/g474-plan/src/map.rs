//! Register addresses and the bit fields the plans use, from RM0440's memory map and register
//! descriptions (cited by chapter title and register name, which do not move between the
//! manual's revisions; section numbers do). Only what the firmware touches is here.
use crate::Register;

const fn reg(peripheral: &'static str, name: &'static str, address: u32) -> Register {
    Register {
        peripheral,
        name,
        address,
    }
}

/// Peripheral base addresses (RM0440 "Memory map and register boundary addresses").
pub mod base {
    /// TIM3 (APB1).
    pub const TIM3: u32 = 0x4000_0400;
    /// TIM4 (APB1).
    pub const TIM4: u32 = 0x4000_0800;
    /// TIM6 (APB1).
    pub const TIM6: u32 = 0x4000_1000;
    /// IWDG (APB1).
    pub const IWDG: u32 = 0x4000_3000;
    /// PWR (APB1).
    pub const PWR: u32 = 0x4000_7000;
    /// LPUART1 (APB1): the host link (the NUCLEO-G474RE's ST-LINK virtual COM port).
    pub const LPUART1: u32 = 0x4000_8000;
    /// TIM1 (APB2).
    pub const TIM1: u32 = 0x4001_2C00;
    /// RCC (AHB1).
    pub const RCC: u32 = 0x4002_1000;
    /// Flash interface registers (AHB1).
    pub const FLASH: u32 = 0x4002_2000;
    /// GPIO port A (AHB2).
    pub const GPIOA: u32 = 0x4800_0000;
    /// GPIO port B (AHB2).
    pub const GPIOB: u32 = 0x4800_0400;
    /// Debug MCU configuration (private peripheral bus).
    pub const DBGMCU: u32 = 0xE004_2000;
}

/// RCC registers and bits (RM0440 "Reset and clock control (RCC)", RCC registers).
pub mod rcc {
    use super::{base::RCC, reg};
    use crate::Register;

    /// Clock control.
    pub const CR: Register = reg("RCC", "CR", RCC);
    /// Clock configuration.
    pub const CFGR: Register = reg("RCC", "CFGR", RCC + 0x08);
    /// Main PLL configuration.
    pub const PLLCFGR: Register = reg("RCC", "PLLCFGR", RCC + 0x0C);
    /// AHB2 clock enable (GPIO ports).
    pub const AHB2ENR: Register = reg("RCC", "AHB2ENR", RCC + 0x4C);
    /// APB1 clock enable 1 (TIM3, TIM4, TIM6, PWR).
    pub const APB1ENR1: Register = reg("RCC", "APB1ENR1", RCC + 0x58);
    /// APB1 clock enable 2 (LPUART1).
    pub const APB1ENR2: Register = reg("RCC", "APB1ENR2", RCC + 0x5C);
    /// APB2 clock enable (TIM1).
    pub const APB2ENR: Register = reg("RCC", "APB2ENR", RCC + 0x60);
    /// Peripherals independent clock configuration (LPUART1's kernel clock).
    pub const CCIPR: Register = reg("RCC", "CCIPR", RCC + 0x88);
    /// Control/status: LSI and the reset flags.
    pub const CSR: Register = reg("RCC", "CSR", RCC + 0x94);

    /// CR: HSI16 on / ready, PLL on / ready.
    pub const CR_HSION: u32 = 1 << 8;
    /// CR: HSI16 ready.
    pub const CR_HSIRDY: u32 = 1 << 10;
    /// CR: main PLL on.
    pub const CR_PLLON: u32 = 1 << 24;
    /// CR: main PLL locked.
    pub const CR_PLLRDY: u32 = 1 << 25;
    /// CFGR: system clock switch, bits 1:0 (11 = PLL).
    pub const CFGR_SW_MASK: u32 = 0b11;
    /// CFGR: SW = PLL.
    pub const CFGR_SW_PLL: u32 = 0b11;
    /// CFGR: system clock switch status, bits 3:2.
    pub const CFGR_SWS_MASK: u32 = 0b11 << 2;
    /// CFGR: SWS = PLL.
    pub const CFGR_SWS_PLL: u32 = 0b11 << 2;
    /// CFGR: AHB prescaler HPRE, bits 7:4 (0xxx = /1, 1000 = /2).
    pub const CFGR_HPRE_MASK: u32 = 0xF << 4;
    /// CFGR: HPRE = /2.
    pub const CFGR_HPRE_DIV2: u32 = 0b1000 << 4;
    /// AHB2ENR: GPIOA / GPIOB clock enable.
    pub const AHB2ENR_GPIOAEN: u32 = 1 << 0;
    /// AHB2ENR: GPIOB clock enable.
    pub const AHB2ENR_GPIOBEN: u32 = 1 << 1;
    /// APB1ENR1: TIM3, TIM4, TIM6, PWR clock enable.
    pub const APB1ENR1_TIM3EN: u32 = 1 << 1;
    /// APB1ENR1: TIM4 clock enable.
    pub const APB1ENR1_TIM4EN: u32 = 1 << 2;
    /// APB1ENR1: TIM6 clock enable.
    pub const APB1ENR1_TIM6EN: u32 = 1 << 4;
    /// APB1ENR1: PWR clock enable.
    pub const APB1ENR1_PWREN: u32 = 1 << 28;
    /// APB1ENR2: LPUART1 clock enable.
    pub const APB1ENR2_LPUART1EN: u32 = 1 << 0;
    /// CCIPR: LPUART1SEL, bits 11:10 (00 = PCLK1, 01 = SYSCLK, 10 = HSI16, 11 = LSE).
    pub const CCIPR_LPUART1SEL_MASK: u32 = 0b11 << 10;
    /// CCIPR: LPUART1SEL = PCLK1.
    pub const CCIPR_LPUART1SEL_PCLK1: u32 = 0b00 << 10;
    /// APB2ENR: TIM1 clock enable.
    pub const APB2ENR_TIM1EN: u32 = 1 << 11;
    /// CSR: remove reset flags (write 1).
    pub const CSR_RMVF: u32 = 1 << 23;
}

/// PWR registers and bits (RM0440 "Power control (PWR)", PWR registers).
pub mod pwr {
    use super::{base::PWR, reg};
    use crate::Register;

    /// Power control 3 (UCPD dead-battery disable).
    pub const CR3: Register = reg("PWR", "CR3", PWR + 0x08);
    /// Power control 5 (range 1 boost).
    pub const CR5: Register = reg("PWR", "CR5", PWR + 0x80);
    /// CR3: UCPD1 dead-battery pull-downs on CC1 (PB6) and CC2 (PB4) disabled.
    pub const CR3_UCPD1_DBDIS: u32 = 1 << 14;
    /// CR5: R1MODE, 1 = range 1 normal, 0 = range 1 boost.
    pub const CR5_R1MODE: u32 = 1 << 8;
}

/// Flash interface (RM0440 "Embedded flash memory (FLASH)", FLASH registers).
pub mod flash {
    use super::{base::FLASH, reg};
    use crate::Register;

    /// Access control: latency, prefetch and caches (the ART accelerator).
    pub const ACR: Register = reg("FLASH", "ACR", FLASH);
    /// ACR: LATENCY, bits 3:0 (wait states).
    pub const ACR_LATENCY_MASK: u32 = 0xF;
    /// ACR: prefetch enable.
    pub const ACR_PRFTEN: u32 = 1 << 8;
    /// ACR: instruction cache enable.
    pub const ACR_ICEN: u32 = 1 << 9;
    /// ACR: data cache enable.
    pub const ACR_DCEN: u32 = 1 << 10;
}

/// Debug MCU (RM0440 "Debug support (DBG)", DBGMCU registers).
pub mod dbgmcu {
    use super::{base::DBGMCU, reg};
    use crate::Register;

    /// Configuration: debug in low-power modes.
    pub const CR: Register = reg("DBGMCU", "CR", DBGMCU + 0x04);
    /// APB1 freeze 1: TIM6, IWDG.
    pub const APB1FZR1: Register = reg("DBGMCU", "APB1FZR1", DBGMCU + 0x08);
    /// APB2 freeze: TIM1.
    pub const APB2FZR: Register = reg("DBGMCU", "APB2FZR", DBGMCU + 0x10);
    /// CR: keep the debug clocks running in Sleep (WFI).
    pub const CR_DBG_SLEEP: u32 = 1 << 0;
    /// APB1FZR1: TIM6 stopped while the core is halted.
    pub const APB1FZR1_TIM6_STOP: u32 = 1 << 4;
    /// APB1FZR1: IWDG stopped while the core is halted.
    pub const APB1FZR1_IWDG_STOP: u32 = 1 << 12;
    /// APB2FZR: TIM1 stopped (and its outputs disabled) while the core is halted.
    pub const APB2FZR_TIM1_STOP: u32 = 1 << 11;
}

/// An advanced-control timer's registers (RM0440 "Advanced-control timers (TIM1/TIM8/TIM20)").
pub mod tim1 {
    use super::{base::TIM1, reg};
    use crate::Register;

    /// Control 1.
    pub const CR1: Register = reg("TIM1", "CR1", TIM1);
    /// Control 2 (output idle states).
    pub const CR2: Register = reg("TIM1", "CR2", TIM1 + 0x04);
    /// Status.
    pub const SR: Register = reg("TIM1", "SR", TIM1 + 0x10);
    /// Event generation.
    pub const EGR: Register = reg("TIM1", "EGR", TIM1 + 0x14);
    /// Capture/compare mode 1 (channels 1 and 2).
    pub const CCMR1: Register = reg("TIM1", "CCMR1", TIM1 + 0x18);
    /// Capture/compare mode 2 (channels 3 and 4).
    pub const CCMR2: Register = reg("TIM1", "CCMR2", TIM1 + 0x1C);
    /// Capture/compare enable.
    pub const CCER: Register = reg("TIM1", "CCER", TIM1 + 0x20);
    /// Prescaler.
    pub const PSC: Register = reg("TIM1", "PSC", TIM1 + 0x28);
    /// Auto-reload.
    pub const ARR: Register = reg("TIM1", "ARR", TIM1 + 0x2C);
    /// Repetition counter.
    pub const RCR: Register = reg("TIM1", "RCR", TIM1 + 0x30);
    /// Compare 1 (axis 0 duty).
    pub const CCR1: Register = reg("TIM1", "CCR1", TIM1 + 0x34);
    /// Compare 2 (axis 1 duty).
    pub const CCR2: Register = reg("TIM1", "CCR2", TIM1 + 0x38);
    /// Compare 3 (unused: channel 3 is forced active, the drive enable).
    pub const CCR3: Register = reg("TIM1", "CCR3", TIM1 + 0x3C);
    /// Break and dead time.
    pub const BDTR: Register = reg("TIM1", "BDTR", TIM1 + 0x44);
    /// Alternate function option 1 (break input sources).
    pub const AF1: Register = reg("TIM1", "AF1", TIM1 + 0x60);

    /// CR1: counter enable.
    pub const CR1_CEN: u32 = 1 << 0;
    /// CR1: centre-aligned mode 1 (CMS = 01, bits 6:5).
    pub const CR1_CMS_CENTER1: u32 = 0b01 << 5;
    /// CR1: auto-reload preload.
    pub const CR1_ARPE: u32 = 1 << 7;
    /// BDTR: main output enable.
    pub const BDTR_MOE: u32 = 1 << 15;
}

/// A general-purpose or basic timer's registers at `base` (RM0440 "General-purpose timers
/// (TIM2/TIM3/TIM4/TIM5)", "Basic timers (TIM6/TIM7)"): the offsets the plans use are the same.
pub mod timx {
    use super::reg;
    use crate::Register;

    /// Control 1.
    pub const fn cr1(p: &'static str, base: u32) -> Register {
        reg(p, "CR1", base)
    }
    /// Slave mode control (encoder mode).
    pub const fn smcr(p: &'static str, base: u32) -> Register {
        reg(p, "SMCR", base + 0x08)
    }
    /// DMA/interrupt enable.
    pub const fn dier(p: &'static str, base: u32) -> Register {
        reg(p, "DIER", base + 0x0C)
    }
    /// Status.
    pub const fn sr(p: &'static str, base: u32) -> Register {
        reg(p, "SR", base + 0x10)
    }
    /// Event generation.
    pub const fn egr(p: &'static str, base: u32) -> Register {
        reg(p, "EGR", base + 0x14)
    }
    /// Capture/compare mode 1 (input mode).
    pub const fn ccmr1(p: &'static str, base: u32) -> Register {
        reg(p, "CCMR1", base + 0x18)
    }
    /// Capture/compare mode 2 (input mode: channels 3 and 4).
    pub const fn ccmr2(p: &'static str, base: u32) -> Register {
        reg(p, "CCMR2", base + 0x1C)
    }
    /// Capture/compare 4 (the counter captured at the index pulse).
    pub const fn ccr4(p: &'static str, base: u32) -> Register {
        reg(p, "CCR4", base + 0x40)
    }
    /// Capture/compare enable.
    pub const fn ccer(p: &'static str, base: u32) -> Register {
        reg(p, "CCER", base + 0x20)
    }
    /// Counter.
    pub const fn cnt(p: &'static str, base: u32) -> Register {
        reg(p, "CNT", base + 0x24)
    }
    /// Prescaler.
    pub const fn psc(p: &'static str, base: u32) -> Register {
        reg(p, "PSC", base + 0x28)
    }
    /// Auto-reload.
    pub const fn arr(p: &'static str, base: u32) -> Register {
        reg(p, "ARR", base + 0x2C)
    }
}

/// IWDG registers and keys (RM0440 "Independent watchdog (IWDG)", §42 in Rev 4).
pub mod iwdg {
    use super::{base::IWDG, reg};
    use crate::Register;

    /// Key.
    pub const KR: Register = reg("IWDG", "KR", IWDG);
    /// Prescaler.
    pub const PR: Register = reg("IWDG", "PR", IWDG + 0x04);
    /// Reload.
    pub const RLR: Register = reg("IWDG", "RLR", IWDG + 0x08);
    /// Status (PVU, RVU, WVU: an update in progress).
    pub const SR: Register = reg("IWDG", "SR", IWDG + 0x0C);
    /// KR: start the watchdog.
    pub const KEY_START: u32 = 0xCCCC;
    /// KR: unlock PR and RLR.
    pub const KEY_UNLOCK: u32 = 0x5555;
    /// KR: reload the counter (the feed).
    pub const KEY_RELOAD: u32 = 0xAAAA;
}

/// LPUART1's registers and bits (RM0440 "Low-power universal asynchronous receiver
/// transmitter (LPUART)", LPUART registers). With FIFO mode on (CR1.FIFOEN), ISR bit 5 reads
/// "RX FIFO not empty" (RXFNE) and bit 7 "TX FIFO not full" (TXFNF); CR1 bit 5 enables the
/// interrupt on RXFNE and on an overrun.
pub mod lpuart {
    use super::{base::LPUART1, reg};
    use crate::Register;

    /// Control 1.
    pub const CR1: Register = reg("LPUART1", "CR1", LPUART1);
    /// Control 2 (stop bits; reset value: 1 stop bit).
    pub const CR2: Register = reg("LPUART1", "CR2", LPUART1 + 0x04);
    /// Control 3 (FIFO thresholds, error interrupt, overrun disable).
    pub const CR3: Register = reg("LPUART1", "CR3", LPUART1 + 0x08);
    /// Baud rate: LPUARTDIV, bits 19:0.
    pub const BRR: Register = reg("LPUART1", "BRR", LPUART1 + 0x0C);
    /// Interrupt and status.
    pub const ISR: Register = reg("LPUART1", "ISR", LPUART1 + 0x1C);
    /// Interrupt flag clear.
    pub const ICR: Register = reg("LPUART1", "ICR", LPUART1 + 0x20);
    /// Receive data (reading it pops the RX FIFO).
    pub const RDR: Register = reg("LPUART1", "RDR", LPUART1 + 0x24);
    /// Transmit data (writing it pushes the TX FIFO).
    pub const TDR: Register = reg("LPUART1", "TDR", LPUART1 + 0x28);
    /// Kernel clock prescaler (PRESCALER bits 3:0; 0 = /1).
    pub const PRESC: Register = reg("LPUART1", "PRESC", LPUART1 + 0x2C);

    /// CR1: LPUART enable.
    pub const CR1_UE: u32 = 1 << 0;
    /// CR1: receiver enable.
    pub const CR1_RE: u32 = 1 << 2;
    /// CR1: transmitter enable.
    pub const CR1_TE: u32 = 1 << 3;
    /// CR1: interrupt on RXFNE (FIFO mode) or ORE.
    pub const CR1_RXFNEIE: u32 = 1 << 5;
    /// CR1: word length bit M0 (with M1 = 0: 8 data bits).
    pub const CR1_M0: u32 = 1 << 12;
    /// CR1: word length bit M1.
    pub const CR1_M1: u32 = 1 << 28;
    /// CR1: FIFO mode (8-byte RX and TX FIFOs); writable only while UE = 0.
    pub const CR1_FIFOEN: u32 = 1 << 29;
    /// ISR: parity error.
    pub const ISR_PE: u32 = 1 << 0;
    /// ISR: framing error.
    pub const ISR_FE: u32 = 1 << 1;
    /// ISR: noise detected.
    pub const ISR_NE: u32 = 1 << 2;
    /// ISR: overrun (a character arrived with the RX FIFO full and was lost).
    pub const ISR_ORE: u32 = 1 << 3;
    /// ISR: RX FIFO not empty.
    pub const ISR_RXFNE: u32 = 1 << 5;
    /// ISR: TX FIFO not full.
    pub const ISR_TXFNF: u32 = 1 << 7;
    /// ISR: transmit enable acknowledge.
    pub const ISR_TEACK: u32 = 1 << 21;
    /// ISR: receive enable acknowledge.
    pub const ISR_REACK: u32 = 1 << 22;
    /// ICR: the error flags' clear bits are at the flags' positions (PECF, FECF, NCF, ORECF).
    pub const ICR_ERRORS: u32 = ISR_PE | ISR_FE | ISR_NE | ISR_ORE;
}

/// GPIO registers of a port at `base` (RM0440 "General-purpose I/Os (GPIO)").
pub mod gpio {
    use super::reg;
    use crate::Register;

    /// Mode (2 bits per pin: 00 input, 01 output, 10 alternate function, 11 analog).
    pub const fn moder(p: &'static str, base: u32) -> Register {
        reg(p, "MODER", base)
    }
    /// Pull-up / pull-down (2 bits per pin: 01 up, 10 down).
    pub const fn pupdr(p: &'static str, base: u32) -> Register {
        reg(p, "PUPDR", base + 0x0C)
    }
    /// Bit set / reset (write-only; bit n + 16 drives pin n low).
    pub const fn bsrr(p: &'static str, base: u32) -> Register {
        reg(p, "BSRR", base + 0x18)
    }
    /// Alternate function, pins 0..7 (4 bits per pin).
    pub const fn afrl(p: &'static str, base: u32) -> Register {
        reg(p, "AFRL", base + 0x20)
    }
    /// Alternate function, pins 8..15.
    pub const fn afrh(p: &'static str, base: u32) -> Register {
        reg(p, "AFRH", base + 0x24)
    }
    /// MODER: general-purpose output.
    pub const MODE_OUTPUT: u32 = 0b01;
    /// MODER: alternate function.
    pub const MODE_AF: u32 = 0b10;
    /// PUPDR: pull-up.
    pub const PULL_UP: u32 = 0b01;
    /// PUPDR: pull-down.
    pub const PULL_DOWN: u32 = 0b10;
}
