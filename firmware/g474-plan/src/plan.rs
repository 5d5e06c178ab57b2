//! The plans, in the order the board applies them, and the board's figures.
//!
//! At boot ([`BOOT`]): [`SAFE_OUTPUTS`] (at the reset clock, before anything can fail: the
//! drive-enable line driven low), [`CLOCK`] (HSI16 → PLL → 170 MHz, range-1 boost, 4 wait
//! states, prefetch and caches; every wait bounded), [`DEBUG_AND_POWER`] (debug freeze, debug
//! in sleep, UCPD dead-battery pull-downs off), [`TIM1_PWM`] (PWM, drive enable and break, and
//! their pins), [`ENCODER_TIM3`], [`ENCODER_TIM4`], [`ENCODER_PINS`], [`TICK_TIMER`] (TIM6);
//! at the end of the app's `init`, [`START_WATCHDOG`]. The
//! drives: [`ENABLE_OUTPUTS`] and [`SAFE_STATE`] (also what HardFault, panic and unexpected
//! interrupts apply). [`CLEAR_RESET_FLAGS`] after the reset cause was read. [`HOST_LINK`]
//! (LPUART1, the host link) when the app takes the link's port.
//!
//! # Pins (STM32G474RE, DS12288 alternate-function table)
//! | pin | function | AF | notes |
//! |---|---|---|---|
//! | PA8 | TIM1_CH1: PWM axis 0 | 6 | pull-down; Hi-Z while TIM1's outputs are off |
//! | PA9 | TIM1_CH2: PWM axis 1 | 6 | pull-down; Hi-Z while TIM1's outputs are off |
//! | PA10 | TIM1_CH3: **drive enable**, active high | 6 | channel 3 forced active: high only while TIM1's main output enable (MOE) is set; external pull-down required |
//! | PB12 | TIM1_BKIN: **safe-torque-off input**, active low | 6 | pull-down: an open STO chain or a broken wire is a break |
//! | PA6, PA7 | TIM3_CH1/CH2: encoder axis 0 | 2 | pull-ups (weak: fit external ones for open-collector encoders) |
//! | PB6, PB7 | TIM4_CH1/CH2: encoder axis 1 | 2 | pull-ups; PB6 is UCPD1_CC1, its dead-battery pull-down is disabled |
//! | PB1 | TIM3_CH4: index pulse of encoder axis 0 (homing) | 2 | pull-down; channel 4 captures the counter on the rising edge |
//! | PB9 | TIM4_CH4: index pulse of encoder axis 1 (homing) | 2 | pull-down; as PB1 (not PB8: that is BOOT0) |
//! | PA2 | LPUART1_TX: host link out | 12 | the NUCLEO-G474RE's ST-LINK virtual COM port ([`HOST_LINK`]) |
//! | PA3 | LPUART1_RX: host link in | 12 | pull-up |
//!
//! **Why the index is a capture, not the encoder-index mode.** RM0440's encoder index (TIMx_ECR)
//! resets the counter at the index, a jump of the reading the encoder check would latch as a
//! glitch. Channel 4 as an input capture latches the counter at the index edge and leaves it
//! counting; homing ties that captured value to the index angle (`EncoderScale::set_reference`).
//!
//! **Why the drive enable is a timer output.** A GPIO enable line keeps its level while the core
//! is halted by a debugger or a HardFault breakpoint. TIM1_CH3 in forced-active mode follows
//! TIM1's main output enable instead, and MOE drops in hardware: on the break input
//! (asynchronously, even without a clock), when the core halts (TIM1 is frozen in debug and its
//! outputs are disabled "as if MOE were reset"), and in software ([`SAFE_STATE`]). With OSSI = 0
//! the disabled outputs are released to Hi-Z, so the enable line's pull-down disables the
//! amplifiers; a reset (the watchdog's included) leaves every pin Hi-Z too. [`SAFE_STATE`] also
//! turns PA10 into a GPIO driven low, so the line is held low actively after a fault.
use controller::watchdog::TIMEOUT_US;

use crate::map::{base, dbgmcu, flash, gpio, iwdg, lpuart, pwr, rcc, tim1, timx};
use crate::{Action, Register, Step};

// ---------------------------------------------------------------------------------------------
// The board's figures.

/// HSI16, the clock at reset and the PLL's source (Hz).
pub const HSI16_HZ: u32 = 16_000_000;
/// PLL input divider M.
pub const PLL_M: u32 = 4;
/// PLL multiplier N.
pub const PLL_N: u32 = 85;
/// PLL output divider R (system clock).
pub const PLL_R: u32 = 2;
/// Core clock: HSI16 / 4 × 85 / 2 = 170 MHz; AHB, APB1 and APB2 undivided.
pub const SYSCLK_HZ: u32 = HSI16_HZ / PLL_M * PLL_N / PLL_R;
/// Flash wait states at 170 MHz in range-1 boost mode.
pub const FLASH_WAIT_STATES: u32 = 4;
/// TIM1's period in counts (its auto-reload): centre-aligned at 170 MHz, 20 kHz PWM. The
/// duty runs 0..=`PWM_MAX_DUTY`; half of it is zero torque.
pub const PWM_MAX_DUTY: u16 = 4250;
/// The duty of zero torque (50 %).
pub const PWM_ZERO_TORQUE_DUTY: u32 = PWM_MAX_DUTY as u32 / 2;
/// TIM6 prescaler: the tick timer counts at 85 MHz.
pub const TIM6_PSC: u32 = 1;
/// TIM6's counter clock (Hz).
pub const TICK_TIMER_HZ: u32 = SYSCLK_HZ / (TIM6_PSC + 1);
/// TIM6 auto-reload for the 2 kHz servo tick.
pub const TIM6_ARR: u32 = TICK_TIMER_HZ / controller::SAMPLE_RATE_HZ - 1;
/// The host link's baud rate (LPUART1, 8 data bits, no parity, 1 stop bit). 115 200 Bd is
/// what every ST-LINK virtual COM port and every host serial driver does exactly; at 11.5 kB/s
/// a full frame of 8 stream knots takes about 20 ms, which the motion stream's buffer covers.
pub const LINK_BAUD: u32 = 115_200;
/// LPUART1's kernel clock (Hz): PCLK1 (`RCC_CCIPR.LPUART1SEL = 00`), APB1 undivided.
pub const LINK_KERNEL_HZ: u32 = SYSCLK_HZ;
/// LPUART1_BRR for [`LINK_BAUD`]: RM0440 "LPUART baud rate generation",
/// `baud = 256 · f_ck / LPUARTDIV` with the prescaler at /1, so LPUARTDIV =
/// round(256 · 170 MHz / 115 200) = 377 778 (0x5_C3B2; the rate is 115 199.9 Bd, 0.6 ppm
/// slow). RM0440's limits: LPUARTDIV ≥ 0x300, 20 bits, and 3 · baud ≤ f_ck ≤ 4096 · baud.
pub const LPUART1_BRR: u32 =
    ((256 * LINK_KERNEL_HZ as u64 + LINK_BAUD as u64 / 2) / LINK_BAUD as u64) as u32;
/// The LSI's nominal frequency, the IWDG's clock (Hz).
pub const LSI_HZ: f32 = 32_000.0;
/// The LSI's range assumed for the timeout bounds (Hz): DS12288's LSI characteristics, taken
/// wide (the datasheet's over temperature and supply is within it).
pub const LSI_RANGE_HZ: (f32, f32) = (29_500.0, 34_000.0);
/// IWDG prescaler register value: 0 is divide by 4 (125 µs per count at 32 kHz).
pub const IWDG_PR: u32 = 0;
/// IWDG reload: [`TIMEOUT_US`] in counts, minus one (the timeout is `RLR + 1` counts).
pub const IWDG_RLR: u32 = (TIMEOUT_US * LSI_HZ / (4.0 * 1.0e6) + 0.5) as u32 - 1;

/// The IWDG timeout (µs) with the LSI at `lsi_hz`: `4 · 2^PR · (RLR + 1) / f_LSI`.
pub fn iwdg_timeout_us(lsi_hz: f32) -> f32 {
    ((4u32 << IWDG_PR) * (IWDG_RLR + 1)) as f32 / lsi_hz * 1.0e6
}

// ---------------------------------------------------------------------------------------------
// Step builders.

const fn write(register: Register, value: u32, why: &'static str) -> Step {
    Step {
        register,
        action: Action::Write(value),
        why,
    }
}
const fn set(register: Register, bits: u32, why: &'static str) -> Step {
    Step {
        register,
        action: Action::Modify {
            clear: 0,
            set: bits,
        },
        why,
    }
}
const fn clear(register: Register, bits: u32, why: &'static str) -> Step {
    Step {
        register,
        action: Action::Modify {
            clear: bits,
            set: 0,
        },
        why,
    }
}
const fn field(register: Register, mask: u32, value: u32, why: &'static str) -> Step {
    Step {
        register,
        action: Action::Modify {
            clear: mask,
            set: value,
        },
        why,
    }
}
const fn wait(register: Register, mask: u32, value: u32, polls: u32, why: &'static str) -> Step {
    Step {
        register,
        action: Action::WaitFor { mask, value, polls },
        why,
    }
}
const fn delay(register: Register, cycles: u32, why: &'static str) -> Step {
    Step {
        register,
        action: Action::Delay { cycles },
        why,
    }
}

/// A pin: port name, port base, number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pin {
    /// `"GPIOA"` or `"GPIOB"`.
    pub port: &'static str,
    /// The port's base address.
    pub base: u32,
    /// 0..15.
    pub n: u32,
}

const fn pa(n: u32) -> Pin {
    Pin {
        port: "GPIOA",
        base: base::GPIOA,
        n,
    }
}
const fn pb(n: u32) -> Pin {
    Pin {
        port: "GPIOB",
        base: base::GPIOB,
        n,
    }
}

/// PWM of axis 0 (TIM1_CH1).
pub const PWM_0: Pin = pa(8);
/// PWM of axis 1 (TIM1_CH2).
pub const PWM_1: Pin = pa(9);
/// Drive enable (TIM1_CH3, forced active while MOE is set).
pub const DRIVE_ENABLE: Pin = pa(10);
/// Safe-torque-off input (TIM1_BKIN, active low).
pub const STO_BREAK: Pin = pb(12);
/// Encoder of axis 0, channels A and B (TIM3).
pub const ENCODER_0: [Pin; 2] = [pa(6), pa(7)];
/// Encoder of axis 1, channels A and B (TIM4).
pub const ENCODER_1: [Pin; 2] = [pb(6), pb(7)];
/// Index pulses of the encoders of axes 0 and 1 (TIM3_CH4, TIM4_CH4).
pub const ENCODER_INDEX: [Pin; 2] = [pb(1), pb(9)];
/// The host link's transmit line (LPUART1_TX, AF12): the NUCLEO-G474RE's ST-LINK virtual COM
/// port receives it (UM2505: LPUART1 on PA2/PA3 to the STLINK-V3E).
pub const LINK_TX: Pin = pa(2);
/// The host link's receive line (LPUART1_RX, AF12).
pub const LINK_RX: Pin = pa(3);
/// The alternate function of LPUART1 on PA2/PA3 (DS12288 alternate-function table: AF7 there
/// is USART2, AF12 LPUART1).
pub const LINK_AF: u32 = 12;

const fn mode(pin: Pin, mode: u32, why: &'static str) -> Step {
    field(
        gpio::moder(pin.port, pin.base),
        0b11 << (2 * pin.n),
        mode << (2 * pin.n),
        why,
    )
}
const fn pull(pin: Pin, pull: u32, why: &'static str) -> Step {
    field(
        gpio::pupdr(pin.port, pin.base),
        0b11 << (2 * pin.n),
        pull << (2 * pin.n),
        why,
    )
}
const fn af(pin: Pin, af: u32, why: &'static str) -> Step {
    let register = if pin.n < 8 {
        gpio::afrl(pin.port, pin.base)
    } else {
        gpio::afrh(pin.port, pin.base)
    };
    let shift = 4 * (pin.n % 8);
    field(register, 0xF << shift, af << shift, why)
}
const fn low(pin: Pin, why: &'static str) -> Step {
    write(gpio::bsrr(pin.port, pin.base), 1 << (pin.n + 16), why)
}

// ---------------------------------------------------------------------------------------------
// Register values.

/// TIM1 CR1 before the counter starts: centre-aligned mode 1, auto-reload preloaded.
pub const TIM1_CR1: u32 = tim1::CR1_CMS_CENTER1 | tim1::CR1_ARPE;
/// TIM1 CCMR1: channels 1 and 2 in PWM mode 1 (OCxM = 0110) with compare preload.
pub const TIM1_CCMR1: u32 = (0b110 << 4) | (1 << 3) | (0b110 << 12) | (1 << 11);
/// TIM1 CCMR2: channel 3 forced active (OC3M = 0101): the drive enable, high while MOE is set.
pub const TIM1_CCMR2: u32 = 0b101 << 4;
/// TIM1 CCER: outputs 1, 2 and 3 enabled, active high.
pub const TIM1_CCER: u32 = (1 << 0) | (1 << 4) | (1 << 8);
/// TIM1 AF1: the break input BRK takes the BKIN pin (BKINE), not inverted (BKINP = 0).
pub const TIM1_AF1: u32 = 1 << 0;
/// TIM1 BDTR at boot, one write: break enabled (BKE), active low (BKP = 0), filtered over 8
/// timer clocks (BKF = 0011, 47 ns), no automatic output re-enable after a break (AOE = 0),
/// outputs released to Hi-Z when off (OSSI = 0), no dead time (the outputs are not a
/// complementary pair), lock level 1 (the break configuration can no longer be changed
/// until reset), main output enable off (MOE = 0: set by [`ENABLE_OUTPUTS`]).
pub const TIM1_BDTR: u32 = (0b0011 << 16) | (1 << 12) | (0b01 << 8);
/// TIM3/TIM4 SMCR: encoder mode 3 (SMS = 0011), counting both edges of both channels.
pub const ENCODER_SMCR: u32 = 0b011;
/// TIM3/TIM4 CCMR1: CC1S = 01 and CC2S = 01 (inputs TI1, TI2), input filters IC1F = IC2F = 0011
/// (8 samples at 170 MHz).
pub const ENCODER_CCMR1: u32 = 0b01 | (0b0011 << 4) | (0b01 << 8) | (0b0011 << 12);
/// TIM3/TIM4 CCMR2: CC4S = 01 (channel 4 an input on TI4, the index pulse), input filter
/// IC4F = 0011; channel 3 unused.
pub const INDEX_CCMR2: u32 = (0b01 << 8) | (0b0011 << 12);
/// TIM3/TIM4 CCER: CC4E, the index capture enabled on the rising edge (CC4P = CC4NP = 0);
/// channels 1 and 2 (the encoder inputs) not inverted (the sign is `Settings::encoders`).
pub const INDEX_CCER: u32 = 1 << 12;
/// TIM3/TIM4 SR: CC4IF, an index pulse was captured (cleared by writing 0).
pub const SR_CC4IF: u32 = 1 << 4;

// ---------------------------------------------------------------------------------------------
// The plans.

/// First, at the reset clock: the drive-enable line an output driven low (a pull-down holds it
/// through reset until here). Nothing can fail before this.
pub static SAFE_OUTPUTS: [Step; 4] = [
    set(
        rcc::AHB2ENR,
        rcc::AHB2ENR_GPIOAEN | rcc::AHB2ENR_GPIOBEN,
        "clock the GPIO ports of the drive, break and encoder pins",
    ),
    low(
        DRIVE_ENABLE,
        "drive-enable output latch low before the pin becomes an output",
    ),
    pull(
        DRIVE_ENABLE,
        gpio::PULL_DOWN,
        "drive enable pulled low whenever nothing drives it",
    ),
    mode(
        DRIVE_ENABLE,
        gpio::MODE_OUTPUT,
        "drive enable actively low from the first microseconds of the boot",
    ),
];

/// HSI16 → PLL (M 4, N 85, R 2) → 170 MHz (RM0440 §6.1.5 "Dynamic voltage scaling management"
/// for the boost sequence; "Read access latency" for the wait states). Every wait is bounded:
/// a clock that does not start stops the plan with the enable line low.
pub static CLOCK: [Step; 14] = [
    set(rcc::APB1ENR1, rcc::APB1ENR1_PWREN, "clock the PWR registers"),
    clear(pwr::CR5, pwr::CR5_R1MODE, "range 1 boost mode, needed above 150 MHz (§6.1.5 step 2)"),
    field(
        flash::ACR,
        flash::ACR_LATENCY_MASK | flash::ACR_PRFTEN | flash::ACR_ICEN | flash::ACR_DCEN,
        FLASH_WAIT_STATES | flash::ACR_PRFTEN | flash::ACR_ICEN | flash::ACR_DCEN,
        "4 wait states for 170 MHz in boost mode, before the clock rises; prefetch and instruction/data caches (the ART accelerator)",
    ),
    wait(flash::ACR, flash::ACR_LATENCY_MASK, FLASH_WAIT_STATES, 1_000, "the new latency is in force (read back) before the switch"),
    set(rcc::CR, rcc::CR_HSION, "HSI16 on (it is at reset; the PLL's source)"),
    wait(rcc::CR, rcc::CR_HSIRDY, rcc::CR_HSIRDY, 100_000, "HSI16 ready"),
    write(
        rcc::PLLCFGR,
        0b10 | ((PLL_M - 1) << 4) | (PLL_N << 8) | (1 << 24) | (((PLL_R / 2) - 1) << 25),
        "PLL from HSI16: /M 4 = 4 MHz in, ×N 85 = 340 MHz VCO, /R 2 = 170 MHz on the R output (PLLREN)",
    ),
    set(rcc::CR, rcc::CR_PLLON, "main PLL on"),
    wait(rcc::CR, rcc::CR_PLLRDY, rcc::CR_PLLRDY, 100_000, "PLL locked"),
    field(rcc::CFGR, rcc::CFGR_HPRE_MASK, rcc::CFGR_HPRE_DIV2, "AHB /2 across the switch to 170 MHz (§6.1.5 step 1)"),
    field(rcc::CFGR, rcc::CFGR_SW_MASK, rcc::CFGR_SW_PLL, "system clock from the PLL"),
    wait(rcc::CFGR, rcc::CFGR_SWS_MASK, rcc::CFGR_SWS_PLL, 100_000, "the switch happened"),
    delay(rcc::CFGR, 200, "at least 1 µs at the new frequency (85 MHz HCLK) before AHB /1 (§6.1.5 step 5)"),
    field(rcc::CFGR, rcc::CFGR_HPRE_MASK, 0, "AHB /1: HCLK = SYSCLK = 170 MHz (APB1, APB2 stay /1)"),
];

/// Debug and power: peripherals that must stop with a halted core, WFI that keeps the debug
/// link, and the USB-C dead-battery pull-down on encoder 1's channel A.
pub static DEBUG_AND_POWER: [Step; 4] = [
    set(dbgmcu::CR, dbgmcu::CR_DBG_SLEEP, "keep the debug clocks in Sleep: idle's WFI must not break RTT or attaching (as embassy and Zephyr do on G4)"),
    set(
        dbgmcu::APB2FZR,
        dbgmcu::APB2FZR_TIM1_STOP,
        "TIM1 stops with a halted core and its outputs are disabled as if MOE were reset: a breakpoint or a HardFault halt removes torque and drops the enable line",
    ),
    set(
        dbgmcu::APB1FZR1,
        dbgmcu::APB1FZR1_TIM6_STOP | dbgmcu::APB1FZR1_IWDG_STOP,
        "the servo tick and the watchdog stop with a halted core (a breakpoint neither resets the chip nor piles up ticks); TIM3/TIM4 keep counting: the joints may move while halted",
    ),
    set(
        pwr::CR3,
        pwr::CR3_UCPD1_DBDIS,
        "UCPD1 dead-battery pull-downs off: ~5 kΩ on CC1 = PB6 (encoder 1 channel A) and CC2 = PB4 from reset until this bit",
    ),
];

/// TIM1 (PWM, drive enable, break) and its pins. TIM1 is configured before its pins are handed
/// to it; its outputs stay off (MOE = 0) until [`ENABLE_OUTPUTS`].
pub static TIM1_PWM: [Step; 27] = [
    set(rcc::APB2ENR, rcc::APB2ENR_TIM1EN, "clock TIM1"),
    write(tim1::CR1, TIM1_CR1, "centre-aligned, preloaded, stopped while configured"),
    write(tim1::PSC, 0, "counter at 170 MHz"),
    write(tim1::ARR, PWM_MAX_DUTY as u32, "170 MHz / (2 × 4250) = 20 kHz, centre-aligned"),
    write(tim1::RCR, 0, "an update every period"),
    write(tim1::CCR1, PWM_ZERO_TORQUE_DUTY, "axis 0 at zero torque (50 %)"),
    write(tim1::CCR2, PWM_ZERO_TORQUE_DUTY, "axis 1 at zero torque (50 %)"),
    write(tim1::CCR3, 0, "unused: channel 3 is forced active"),
    write(tim1::CCMR1, TIM1_CCMR1, "channels 1, 2: PWM mode 1, preloaded"),
    write(tim1::CCMR2, TIM1_CCMR2, "channel 3 forced active: the drive enable follows MOE"),
    write(tim1::CCER, TIM1_CCER, "outputs 1, 2, 3 enabled (they drive only while MOE is set)"),
    write(tim1::CR2, 0, "idle levels low (unused with OSSI = 0)"),
    write(tim1::AF1, TIM1_AF1, "break from the BKIN pin (PB12), not inverted"),
    write(tim1::BDTR, TIM1_BDTR, "break enabled, active low, filtered; no automatic re-enable; Hi-Z when off; locked; MOE off"),
    write(tim1::EGR, 1, "load the preloaded registers (UG)"),
    write(tim1::SR, 0, "clear the flags the update set"),
    set(tim1::CR1, tim1::CR1_CEN, "start the PWM counter (outputs still off)"),
    af(PWM_0, 6, "PA8 = TIM1_CH1"),
    pull(PWM_0, gpio::PULL_DOWN, "PWM 0 low when released"),
    mode(PWM_0, gpio::MODE_AF, "PA8 to TIM1"),
    af(PWM_1, 6, "PA9 = TIM1_CH2"),
    pull(PWM_1, gpio::PULL_DOWN, "PWM 1 low when released"),
    mode(PWM_1, gpio::MODE_AF, "PA9 to TIM1"),
    af(DRIVE_ENABLE, 6, "PA10 = TIM1_CH3 (handed over by ENABLE_OUTPUTS; a driven-low output until then)"),
    af(STO_BREAK, 6, "PB12 = TIM1_BKIN"),
    pull(STO_BREAK, gpio::PULL_DOWN, "an open safe-torque-off input reads as a break"),
    mode(STO_BREAK, gpio::MODE_AF, "PB12 to TIM1's break"),
];

/// A general-purpose timer as a quadrature counter (encoder mode 3, full 16-bit range).
const fn encoder_timer(name: &'static str, base: u32) -> [Step; 9] {
    [
        write(timx::cr1(name, base), 0, "stopped while configured"),
        write(timx::smcr(name, base), ENCODER_SMCR, "encoder mode 3"),
        write(
            timx::ccmr1(name, base),
            ENCODER_CCMR1,
            "TI1, TI2 inputs, filtered",
        ),
        write(
            timx::ccmr2(name, base),
            INDEX_CCMR2,
            "TI4 input: the index pulse, filtered",
        ),
        write(
            timx::ccer(name, base),
            INDEX_CCER,
            "both inputs non-inverted (the sign is Settings::encoders); index capture on",
        ),
        write(timx::sr(name, base), 0, "no index captured yet"),
        write(
            timx::arr(name, base),
            0xFFFF,
            "full 16-bit range (extended to 32 bits in software)",
        ),
        write(
            timx::cnt(name, base),
            0,
            "count from 0 (homing sets the zero)",
        ),
        write(timx::cr1(name, base), 1, "start counting"),
    ]
}

/// The encoder of axis 0 (TIM3).
pub static ENCODER_TIM3: [Step; 9] = encoder_timer("TIM3", base::TIM3);
/// The encoder of axis 1 (TIM4).
pub static ENCODER_TIM4: [Step; 9] = encoder_timer("TIM4", base::TIM4);

/// The encoder timers' clocks and pins (the pins after the timers, so the first edge counts).
pub static ENCODER_PINS: [Step; 19] = [
    set(
        rcc::APB1ENR1,
        rcc::APB1ENR1_TIM3EN | rcc::APB1ENR1_TIM4EN,
        "clock TIM3, TIM4",
    ),
    af(ENCODER_0[0], 2, "PA6 = TIM3_CH1"),
    af(ENCODER_0[1], 2, "PA7 = TIM3_CH2"),
    af(ENCODER_1[0], 2, "PB6 = TIM4_CH1"),
    af(ENCODER_1[1], 2, "PB7 = TIM4_CH2"),
    pull(
        ENCODER_0[0],
        gpio::PULL_UP,
        "weak pull-up (open-collector encoders need external ones too)",
    ),
    pull(ENCODER_0[1], gpio::PULL_UP, "weak pull-up"),
    pull(ENCODER_1[0], gpio::PULL_UP, "weak pull-up"),
    pull(ENCODER_1[1], gpio::PULL_UP, "weak pull-up"),
    mode(ENCODER_0[0], gpio::MODE_AF, "PA6 to TIM3"),
    mode(ENCODER_0[1], gpio::MODE_AF, "PA7 to TIM3"),
    mode(ENCODER_1[0], gpio::MODE_AF, "PB6 to TIM4"),
    mode(ENCODER_1[1], gpio::MODE_AF, "PB7 to TIM4"),
    af(ENCODER_INDEX[0], 2, "PB1 = TIM3_CH4 (index, axis 0)"),
    af(ENCODER_INDEX[1], 2, "PB9 = TIM4_CH4 (index, axis 1)"),
    pull(
        ENCODER_INDEX[0],
        gpio::PULL_DOWN,
        "no index without a signal",
    ),
    pull(
        ENCODER_INDEX[1],
        gpio::PULL_DOWN,
        "no index without a signal",
    ),
    mode(ENCODER_INDEX[0], gpio::MODE_AF, "PB1 to TIM3"),
    mode(ENCODER_INDEX[1], gpio::MODE_AF, "PB9 to TIM4"),
];

const TIM6: &str = "TIM6";

/// TIM6, the 2 kHz servo tick: configured, not started (the app starts it at the end of init).
pub static TICK_TIMER: [Step; 7] = [
    set(rcc::APB1ENR1, rcc::APB1ENR1_TIM6EN, "clock TIM6"),
    write(
        timx::cr1(TIM6, base::TIM6),
        1 << 2,
        "URS: only an overflow sets the update flag",
    ),
    write(timx::psc(TIM6, base::TIM6), TIM6_PSC, "counter at 85 MHz"),
    write(
        timx::arr(TIM6, base::TIM6),
        TIM6_ARR,
        "85 MHz / 42500 = 2 kHz",
    ),
    write(
        timx::egr(TIM6, base::TIM6),
        1,
        "UG: load PSC and ARR (URS keeps it from setting the flag)",
    ),
    write(timx::sr(TIM6, base::TIM6), 0, "no tick pending"),
    write(
        timx::dier(TIM6, base::TIM6),
        1,
        "UIE: the update interrupt is SERVO_TICK (IRQ 54)",
    ),
];

/// Starts the IWDG with [`TIMEOUT_US`] (RM0440 "Independent watchdog (IWDG)", §42.3 in Rev 4:
/// start, unlock, prescaler, reload, wait for the update, refresh). It cannot be stopped.
pub static START_WATCHDOG: [Step; 6] = [
    write(
        iwdg::KR,
        iwdg::KEY_START,
        "start the watchdog (and the LSI)",
    ),
    write(iwdg::KR, iwdg::KEY_UNLOCK, "unlock PR and RLR"),
    write(iwdg::PR, IWDG_PR, "LSI / 4: 125 µs per count"),
    write(
        iwdg::RLR,
        IWDG_RLR,
        "24 counts: 3 ms (2.82 to 3.25 ms over the LSI's range)",
    ),
    wait(
        iwdg::SR,
        0b111,
        0,
        1_000_000,
        "prescaler and reload updated (a few LSI cycles)",
    ),
    write(iwdg::KR, iwdg::KEY_RELOAD, "reload with the new timeout"),
];

/// The drives on: PA10 to TIM1 (CH3, forced active), then MOE. A break that is active keeps
/// MOE low (the enable line stays low): the first PWM write then reports the outputs off.
pub static ENABLE_OUTPUTS: [Step; 2] = [
    mode(
        DRIVE_ENABLE,
        gpio::MODE_AF,
        "the drive enable follows TIM1_CH3, i.e. MOE",
    ),
    set(
        tim1::BDTR,
        tim1::BDTR_MOE,
        "main outputs on: PWM and drive enable",
    ),
];

/// The safe state, from any context (fault handlers included; registers only, no RAM): duty
/// to zero torque, then TIM1's outputs off (MOE), then the enable line a GPIO driven low.
pub static SAFE_STATE: [Step; 5] = [
    write(tim1::CCR1, PWM_ZERO_TORQUE_DUTY, "axis 0 to zero torque"),
    write(tim1::CCR2, PWM_ZERO_TORQUE_DUTY, "axis 1 to zero torque"),
    clear(
        tim1::BDTR,
        tim1::BDTR_MOE,
        "TIM1 outputs off (Hi-Z): PWM released, enable dropped",
    ),
    low(DRIVE_ENABLE, "enable output latch low"),
    mode(
        DRIVE_ENABLE,
        gpio::MODE_OUTPUT,
        "enable line actively driven low, whatever TIM1 does",
    ),
];

/// The host link's UART, LPUART1 at [`LINK_BAUD`] 8N1, FIFO mode, receive interrupt on
/// (`LINK_RX`, IRQ 91 `LPUART1`), on PA2/PA3. Applied by the board's `link()` after [`BOOT`]
/// (GPIOA is clocked there). RM0440 "LPUART character transmission/reception procedure": the
/// frame format, FIFO mode and baud rate while UE = 0, then UE, then TE and RE, and their
/// acknowledgement (TEACK, REACK) before use. The pins go to the LPUART last, so TX idles
/// high from its first driven instant. A wait that times out leaves the link off, not the
/// machine: the board logs it and runs without a link (the drives stay as they are). The app
/// applies it before it starts the 3 ms watchdog: the acknowledgement wait may take up to
/// ~100 000 register reads (a few ms) when the LPUART is dead.
pub static HOST_LINK: [Step; 16] = [
    set(rcc::APB1ENR2, rcc::APB1ENR2_LPUART1EN, "clock LPUART1"),
    field(
        rcc::CCIPR,
        rcc::CCIPR_LPUART1SEL_MASK,
        rcc::CCIPR_LPUART1SEL_PCLK1,
        "LPUART1 kernel clock = PCLK1, 170 MHz",
    ),
    write(
        lpuart::CR1,
        lpuart::CR1_FIFOEN,
        "disabled (UE = 0) to configure it: FIFO mode, 8 data bits (M1 M0 = 00), no parity",
    ),
    write(lpuart::CR2, 0, "1 stop bit, no inversion, LSB first"),
    write(
        lpuart::CR3,
        0,
        "no flow control (the VCP has none), no DMA, overrun detection on",
    ),
    write(lpuart::PRESC, 0, "kernel clock undivided"),
    write(
        lpuart::BRR,
        LPUART1_BRR,
        "LPUARTDIV = 256 x 170 MHz / 115200 Bd = 377778",
    ),
    set(lpuart::CR1, lpuart::CR1_UE, "enable the LPUART"),
    set(
        lpuart::CR1,
        lpuart::CR1_TE | lpuart::CR1_RE | lpuart::CR1_RXFNEIE,
        "transmitter, receiver, interrupt on a received byte or an overrun",
    ),
    wait(
        lpuart::ISR,
        lpuart::ISR_TEACK | lpuart::ISR_REACK,
        lpuart::ISR_TEACK | lpuart::ISR_REACK,
        100_000,
        "TE and RE acknowledged",
    ),
    write(lpuart::ICR, lpuart::ICR_ERRORS, "no stale error flag"),
    af(LINK_TX, LINK_AF, "PA2 = LPUART1_TX"),
    af(LINK_RX, LINK_AF, "PA3 = LPUART1_RX"),
    pull(
        LINK_RX,
        gpio::PULL_UP,
        "RX idles high while nothing drives it: no false start bits",
    ),
    mode(LINK_TX, gpio::MODE_AF, "PA2 to LPUART1"),
    mode(LINK_RX, gpio::MODE_AF, "PA3 to LPUART1"),
];

/// Clears the reset flags after they were read (RCC_CSR RMVF).
pub static CLEAR_RESET_FLAGS: [Step; 1] = [set(
    rcc::CSR,
    rcc::CSR_RMVF,
    "clear the reset flags for the next boot",
)];

/// The boot plans in the order the board applies them.
pub static BOOT: [&[Step]; 8] = [
    &SAFE_OUTPUTS,
    &CLOCK,
    &DEBUG_AND_POWER,
    &TIM1_PWM,
    &ENCODER_TIM3,
    &ENCODER_TIM4,
    &ENCODER_PINS,
    &TICK_TIMER,
];
