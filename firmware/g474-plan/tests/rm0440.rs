//! The STM32G474 board's register plan, checked against the reference manual (RM0440) and the
//! datasheet (DS12288) on the host.
//!
//! The plans are applied to a simulated register file that starts from RM0440's reset values
//! and answers the ready flags the plans wait for; the tests then read the registers back and
//! decode them with field positions and addresses written out here from the manual, not taken
//! from the crate, so a wrong constant in the crate fails a test instead of agreeing with it.
//! Each test names the RM0440 chapter (and section where its number is certain) it relies on.
use std::collections::BTreeMap;

use controller::watchdog::{ResetCause, MIN_TIMEOUT_US, TIMEOUT_US};
use g474_plan::plan::{
    self, BOOT, CLOCK, ENABLE_OUTPUTS, HOST_LINK, SAFE_OUTPUTS, SAFE_STATE, START_WATCHDOG,
};
use g474_plan::reset::reset_cause;
use g474_plan::{apply, Action, Bus, Step};

// Addresses (RM0440 memory map and register maps).
const RCC: u32 = 0x4002_1000;
const RCC_CR: u32 = RCC;
const RCC_CFGR: u32 = RCC + 0x08;
const RCC_PLLCFGR: u32 = RCC + 0x0C;
const RCC_AHB2ENR: u32 = RCC + 0x4C;
const RCC_APB1ENR1: u32 = RCC + 0x58;
const RCC_APB1ENR2: u32 = RCC + 0x5C;
const RCC_APB2ENR: u32 = RCC + 0x60;
const RCC_CCIPR: u32 = RCC + 0x88;
const RCC_CSR: u32 = RCC + 0x94;
const FLASH_ACR: u32 = 0x4002_2000;
const PWR: u32 = 0x4000_7000;
const PWR_CR3: u32 = PWR + 0x08;
const PWR_CR5: u32 = PWR + 0x80;
const DBGMCU_CR: u32 = 0xE004_2004;
const DBGMCU_APB1FZR1: u32 = 0xE004_2008;
const DBGMCU_APB2FZR: u32 = 0xE004_2010;
const TIM1: u32 = 0x4001_2C00;
const TIM3: u32 = 0x4000_0400;
const TIM4: u32 = 0x4000_0800;
const TIM6: u32 = 0x4000_1000;
const IWDG_KR: u32 = 0x4000_3000;
const IWDG_PR: u32 = 0x4000_3004;
const IWDG_RLR: u32 = 0x4000_3008;
const IWDG_SR: u32 = 0x4000_300C;
const LPUART1: u32 = 0x4000_8000;
const LPUART1_CR1: u32 = LPUART1;
const LPUART1_CR2: u32 = LPUART1 + 0x04;
const LPUART1_CR3: u32 = LPUART1 + 0x08;
const LPUART1_BRR: u32 = LPUART1 + 0x0C;
const LPUART1_ISR: u32 = LPUART1 + 0x1C;
const LPUART1_PRESC: u32 = LPUART1 + 0x2C;
const GPIOA: u32 = 0x4800_0000;
const GPIOB: u32 = 0x4800_0400;
// Timer register offsets.
const CR1: u32 = 0x00;
const CR2: u32 = 0x04;
const SMCR: u32 = 0x08;
const DIER: u32 = 0x0C;
const CCMR1: u32 = 0x18;
const CCMR2: u32 = 0x1C;
const CCER: u32 = 0x20;
const PSC: u32 = 0x28;
const ARR: u32 = 0x2C;
const CCR1: u32 = 0x34;
const CCR2: u32 = 0x38;
const BDTR: u32 = 0x44;
const AF1: u32 = 0x60;
// GPIO register offsets.
const MODER: u32 = 0x00;
const PUPDR: u32 = 0x0C;
const ODR: u32 = 0x14;
const BSRR: u32 = 0x18;
const AFRL: u32 = 0x20;
const AFRH: u32 = 0x24;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Event {
    Write(u32, u32),
    Delay(u32),
}

/// A register file at RM0440's reset values that sets the ready flags the plans wait for.
struct Sim {
    regs: BTreeMap<u32, u32>,
    events: Vec<Event>,
    /// Whether the PLL locks when switched on.
    pll_locks: bool,
    /// Whether LPUART1 acknowledges TE and RE (TEACK, REACK).
    lpuart_acks: bool,
}

impl Sim {
    fn at_reset() -> Self {
        let regs = BTreeMap::from([
            (RCC_CR, (1 << 8) | (1 << 10)),   // HSI16 on and ready
            (RCC_CFGR, 0b0101),               // SW = SWS = HSI16
            (RCC_CSR, (1 << 26) | (1 << 27)), // PINRSTF, BORRSTF: a power-on
            (FLASH_ACR, 0x0004_0600),         // caches on, 0 wait states
            (PWR_CR5, 1 << 8),                // R1MODE = 1: range 1 normal
            (GPIOA + MODER, 0xABFF_FFFF),     // analog, except the debug pins
            (GPIOB + MODER, 0xFFFF_FEBF),
            (GPIOA + PUPDR, 0x6400_0000),
            (GPIOB + PUPDR, 0x0000_0100),
            (TIM1 + AF1, 1),
        ]);
        Sim {
            regs,
            events: Vec::new(),
            pll_locks: true,
            lpuart_acks: true,
        }
    }

    fn get(&self, address: u32) -> u32 {
        *self.regs.get(&address).unwrap_or(&0)
    }

    /// Index of the first write to `address` whose value satisfies `f`.
    fn first_write(&self, address: u32, f: impl Fn(u32) -> bool) -> Option<usize> {
        self.events
            .iter()
            .position(|e| matches!(*e, Event::Write(a, v) if a == address && f(v)))
    }

    fn boot() -> Self {
        let mut sim = Sim::at_reset();
        for p in BOOT {
            apply(p, &mut sim).expect("boot plan");
        }
        sim
    }
}

impl Bus for Sim {
    fn read(&mut self, address: u32) -> u32 {
        let v = self.get(address);
        match address {
            // HSIRDY follows HSION, PLLRDY follows PLLON (if the PLL locks).
            RCC_CR => {
                let hsirdy = (v >> 8) & 1;
                let pllrdy = ((v >> 24) & 1) & self.pll_locks as u32;
                (v & !((1 << 10) | (1 << 25))) | (hsirdy << 10) | (pllrdy << 25)
            }
            // SWS follows SW.
            RCC_CFGR => (v & !0b1100) | ((v & 0b11) << 2),
            // Updates finish at once.
            IWDG_SR => 0,
            // TEACK (21) follows TE (3), REACK (22) follows RE (2), once UE (0) is set.
            LPUART1_ISR => {
                let cr1 = self.get(LPUART1_CR1);
                let on = (cr1 & 1) * self.lpuart_acks as u32;
                (((cr1 >> 3) & on) << 21) | (((cr1 >> 2) & on) << 22)
            }
            _ => v,
        }
    }

    fn write(&mut self, address: u32, value: u32) {
        self.events.push(Event::Write(address, value));
        if address == GPIOA + BSRR || address == GPIOB + BSRR {
            let odr = address - BSRR + ODR;
            let v = (self.get(odr) | (value & 0xFFFF)) & !(value >> 16);
            self.regs.insert(odr, v);
        } else {
            self.regs.insert(address, value);
        }
    }

    fn delay(&mut self, cycles: u32) {
        self.events.push(Event::Delay(cycles));
    }
}

fn bits(v: u32, hi: u32, lo: u32) -> u32 {
    (v >> lo) & ((1 << (hi - lo + 1)) - 1)
}

fn pin_mode(sim: &Sim, port: u32, n: u32) -> u32 {
    bits(sim.get(port + MODER), 2 * n + 1, 2 * n)
}
fn pin_pull(sim: &Sim, port: u32, n: u32) -> u32 {
    bits(sim.get(port + PUPDR), 2 * n + 1, 2 * n)
}
fn pin_af(sim: &Sim, port: u32, n: u32) -> u32 {
    let r = if n < 8 {
        sim.get(port + AFRL)
    } else {
        sim.get(port + AFRH)
    };
    bits(r, 4 * (n % 8) + 3, 4 * (n % 8))
}

/// RM0440 "Reset and clock control (RCC)": RCC_PLLCFGR (PLLSRC bits 1:0 = 10 HSI16, PLLM bits
/// 7:4 = M - 1, PLLN bits 14:8, PLLREN bit 24, PLLR bits 26:25 = R/2 - 1), the PLL's ranges
/// (input 2.66..16 MHz, VCO 96..344 MHz, R output at most 170 MHz), RCC_CFGR (SW = 11 PLL,
/// HPRE/PPRE1/PPRE2 /1): the core, AHB and both APB clocks at 170 MHz from HSI16.
#[test]
fn rm0440_rcc_the_clock_tree_is_170_mhz_from_hsi16() {
    let sim = Sim::boot();
    let pll = sim.get(RCC_PLLCFGR);
    assert_eq!(bits(pll, 1, 0), 0b10, "PLLSRC = HSI16");
    let m = bits(pll, 7, 4) + 1;
    let n = bits(pll, 14, 8);
    let r = 2 * (bits(pll, 26, 25) + 1);
    assert_eq!(
        bits(pll, 24, 24),
        1,
        "PLLREN: the R output feeds the system clock"
    );
    assert_eq!((m, n, r), (4, 85, 2));
    let input_hz = 16_000_000 / m;
    let vco_hz = input_hz * n;
    assert!((2_660_000..=16_000_000).contains(&input_hz), "{input_hz}");
    assert!((96_000_000..=344_000_000).contains(&vco_hz), "{vco_hz}");
    let sysclk = vco_hz / r;
    assert_eq!(sysclk, 170_000_000);
    assert_eq!(plan::SYSCLK_HZ, sysclk);
    let cfgr = sim.get(RCC_CFGR);
    assert_eq!(bits(cfgr, 1, 0), 0b11, "SW = PLL");
    assert_eq!(bits(cfgr, 7, 4) & 0b1000, 0, "HPRE /1: HCLK = 170 MHz");
    assert_eq!(
        bits(cfgr, 10, 8) & 0b100,
        0,
        "PPRE1 /1: APB1 timers at 170 MHz"
    );
    assert_eq!(
        bits(cfgr, 13, 11) & 0b100,
        0,
        "PPRE2 /1: APB2 timers (TIM1) at 170 MHz"
    );
    assert_eq!(sim.get(RCC_CR) & (1 << 24), 1 << 24, "PLLON");
}

/// RM0440 "Embedded flash memory (FLASH)", section "Read access latency" (table "Number of
/// wait states according to CPU clock (HCLK) frequency"): 4 wait states for 136..170 MHz in
/// range 1 boost mode, set and read back before the clock rises; prefetch and the instruction
/// and data caches (the ART accelerator) on.
#[test]
fn rm0440_flash_4_wait_states_before_the_switch_and_the_art_accelerator_on() {
    let sim = Sim::boot();
    let acr = sim.get(FLASH_ACR);
    assert_eq!(bits(acr, 3, 0), 4, "LATENCY");
    assert_eq!(
        acr & ((1 << 8) | (1 << 9) | (1 << 10)),
        (1 << 8) | (1 << 9) | (1 << 10),
        "PRFTEN, ICEN, DCEN"
    );
    let latency = sim.first_write(FLASH_ACR, |v| bits(v, 3, 0) == 4).unwrap();
    let switch = sim
        .first_write(RCC_CFGR, |v| bits(v, 1, 0) == 0b11)
        .unwrap();
    assert!(latency < switch, "wait states before the switch");
    // The latency is read back (a bounded wait) between the two.
    let readback = CLOCK.iter().position(|s| {
        s.register.address == FLASH_ACR && matches!(s.action, Action::WaitFor { .. })
    });
    let switch_step = CLOCK.iter().position(|s| {
        s.register.address == RCC_CFGR
            && s.action
                == Action::Modify {
                    clear: 0b11,
                    set: 0b11,
                }
    });
    assert!(readback.unwrap() < switch_step.unwrap());
}

/// RM0440 §6.1.5 "Dynamic voltage scaling management", the sequence to range 1 boost mode
/// (needed above 150 MHz): AHB divided by 2, R1MODE cleared, wait states, switch, at least
/// 1 µs, AHB back to /1. PWR_CR5 is reachable only with PWREN set (RCC_APB1ENR1 bit 28).
#[test]
fn rm0440_6_1_5_boost_mode_sequence() {
    let sim = Sim::boot();
    assert_eq!(sim.get(PWR_CR5) & (1 << 8), 0, "R1MODE = 0: boost");
    let pwren = sim
        .first_write(RCC_APB1ENR1, |v| v & (1 << 28) != 0)
        .unwrap();
    let first_pwr = sim
        .events
        .iter()
        .position(|e| matches!(*e, Event::Write(a, _) if (PWR..PWR + 0x400).contains(&a)));
    assert!(
        pwren < first_pwr.unwrap(),
        "PWR clocked before it is written"
    );
    let boost = sim.first_write(PWR_CR5, |v| v & (1 << 8) == 0).unwrap();
    let div2 = sim
        .first_write(RCC_CFGR, |v| bits(v, 7, 4) == 0b1000)
        .unwrap();
    let switch = sim
        .first_write(RCC_CFGR, |v| bits(v, 1, 0) == 0b11)
        .unwrap();
    let div1 = sim
        .events
        .iter()
        .rposition(|e| matches!(*e, Event::Write(a, v) if a == RCC_CFGR && bits(v, 7, 4) == 0))
        .unwrap();
    assert!(boost < switch && div2 < switch && switch < div1);
    // The HCLK of 85 MHz between the switch and /1: at least 85 cycles (1 µs).
    let waited: u32 = sim.events[switch..div1]
        .iter()
        .map(|e| if let Event::Delay(c) = e { *c } else { 0 })
        .sum();
    assert!(waited >= 85, "{waited} cycles");
    // The switch itself is confirmed (SWS) before the delay.
    assert!(CLOCK.iter().any(|s| s.register.address == RCC_CFGR
        && s.action
            == Action::WaitFor {
                mask: 0b1100,
                value: 0b1100,
                polls: 100_000
            }));
}

/// Every wait is bounded, and a PLL that never locks stops the boot at that wait with the
/// drive-enable pin an output driven low (SAFE_OUTPUTS ran first) and TIM1 untouched.
#[test]
fn a_clock_that_does_not_start_ends_the_boot_with_the_enable_pin_driven_low() {
    for p in BOOT
        .iter()
        .chain([&START_WATCHDOG[..], &HOST_LINK[..]].iter())
    {
        for s in p.iter() {
            if let Action::WaitFor { polls, .. } = s.action {
                assert!((1..=1_000_000).contains(&polls), "{}: {polls}", s.why);
            }
        }
    }
    let mut sim = Sim::at_reset();
    sim.pll_locks = false;
    apply(&SAFE_OUTPUTS, &mut sim).unwrap();
    let failed: &Step = apply(&CLOCK, &mut sim).unwrap_err();
    assert_eq!(
        (failed.register.address, failed.action),
        (
            RCC_CR,
            Action::WaitFor {
                mask: 1 << 25,
                value: 1 << 25,
                polls: 100_000
            }
        )
    );
    assert_eq!(pin_mode(&sim, GPIOA, 10), 0b01, "PA10 an output");
    assert_eq!(sim.get(GPIOA + ODR) & (1 << 10), 0, "driven low");
    assert_eq!(pin_pull(&sim, GPIOA, 10), 0b10, "and pulled down");
    assert!(sim
        .events
        .iter()
        .all(|e| !matches!(*e, Event::Write(a, _) if (TIM1..TIM1 + 0x400).contains(&a))));
    assert_eq!(bits(sim.get(RCC_CFGR), 1, 0), 0b01, "still on HSI16");
    // The enable pin is driven low before anything else is configured.
    let sim = Sim::boot();
    let low = sim
        .first_write(GPIOA + BSRR, |v| v & (1 << 26) != 0)
        .unwrap();
    let output = sim
        .first_write(GPIOA + MODER, |v| bits(v, 21, 20) == 0b01)
        .unwrap();
    assert!(
        low < output && output < 6,
        "latch low, then output, in the first steps"
    );
}

/// RM0440 "Basic timers (TIM6/TIM7)": f_update = f_TIMCLK / ((PSC + 1)(ARR + 1)); TIMCLK is
/// PCLK1 when APB1 is undivided ("Reset and clock control", timer clock). 2 kHz exactly, the
/// update interrupt enabled, URS set, and the counter not started by the plan (the app starts
/// it at the end of init).
#[test]
fn rm0440_tim6_ticks_at_exactly_2_khz() {
    let sim = Sim::boot();
    let (psc, arr) = (sim.get(TIM6 + PSC), sim.get(TIM6 + ARR));
    assert_eq!(170_000_000 % ((psc + 1) * (arr + 1)), 0);
    assert_eq!(170_000_000 / ((psc + 1) * (arr + 1)), 2_000);
    assert_eq!(sim.get(TIM6 + DIER) & 1, 1, "UIE");
    assert_eq!(sim.get(TIM6 + CR1), 1 << 2, "URS, not started");
    assert_eq!(sim.get(RCC_APB1ENR1) & (1 << 4), 1 << 4, "TIM6EN");
    assert_eq!((plan::TICK_TIMER_HZ, plan::TIM6_ARR), (85_000_000, 42_499));
}

/// RM0440 "Advanced-control timers (TIM1/TIM8/TIM20)": centre-aligned mode 1 (CMS = 01)
/// counts up and down, f_PWM = f_TIMCLK / (2 · ARR · (PSC + 1)) = 20 kHz; PWM mode 1 is
/// OCxM = 0110 (bits 6:4 and 16), forced active 0101; the outputs drive only while BDTR.MOE is
/// set, which the boot leaves off; "Using the break function": BKE enables the break, BKP = 0
/// with AF1.BKINP = 0 makes BKIN active low, AF1.BKINE routes the BKIN pin, AOE = 0 keeps MOE
/// off after a break until software sets it, OSSI = 0 releases the disabled outputs (Hi-Z);
/// LOCK = 01 freezes that configuration until reset.
#[test]
fn rm0440_tim1_20_khz_centre_aligned_with_the_break_enabled_and_the_outputs_off() {
    let sim = Sim::boot();
    let t = |off| sim.get(TIM1 + off);
    assert_eq!(bits(t(CR1), 6, 5), 0b01, "CMS = centre-aligned mode 1");
    assert_eq!(t(CR1) & 1, 1, "counter running");
    assert_eq!(170_000_000 / (2 * t(ARR) * (t(PSC) + 1)), 20_000);
    assert_eq!(170_000_000 % (2 * t(ARR) * (t(PSC) + 1)), 0);
    assert_eq!(
        (t(CCR1), t(CCR2)),
        (t(ARR) / 2, t(ARR) / 2),
        "both axes at 50 %: zero torque"
    );
    let ccmr1 = t(CCMR1);
    assert_eq!(
        (bits(ccmr1, 6, 4), bits(ccmr1, 16, 16)),
        (0b110, 0),
        "OC1M = PWM mode 1"
    );
    assert_eq!(
        (bits(ccmr1, 14, 12), bits(ccmr1, 24, 24)),
        (0b110, 0),
        "OC2M = PWM mode 1"
    );
    assert_eq!(
        (bits(ccmr1, 3, 3), bits(ccmr1, 11, 11)),
        (1, 1),
        "compare preload on both"
    );
    assert_eq!(
        (bits(ccmr1, 1, 0), bits(ccmr1, 9, 8)),
        (0, 0),
        "channels 1, 2 are outputs"
    );
    let ccmr2 = t(CCMR2);
    assert_eq!(
        (bits(ccmr2, 6, 4), bits(ccmr2, 16, 16), bits(ccmr2, 1, 0)),
        (0b101, 0, 0),
        "OC3M = forced active"
    );
    let ccer = t(CCER);
    assert_eq!(ccer & 0x111, 0x111, "CC1E, CC2E, CC3E");
    assert_eq!(ccer & 0x222, 0, "active high");
    assert_eq!(ccer & 0x444, 0, "no complementary outputs");
    let bdtr = t(BDTR);
    assert_eq!(
        bits(bdtr, 15, 15),
        0,
        "MOE off after boot: no torque until the drives are enabled"
    );
    assert_eq!(bits(bdtr, 12, 12), 1, "BKE: break enabled");
    assert_eq!(bits(bdtr, 13, 13), 0, "BKP = 0: break active low");
    assert_eq!(
        bits(bdtr, 14, 14),
        0,
        "AOE = 0: a break keeps the outputs off"
    );
    assert_eq!(
        bits(bdtr, 10, 10),
        0,
        "OSSI = 0: outputs released to Hi-Z when off"
    );
    assert_eq!(bits(bdtr, 9, 8), 0b01, "LOCK level 1");
    assert!(bits(bdtr, 19, 16) != 0, "break filtered");
    assert_eq!(bits(t(AF1), 0, 0), 1, "BKINE: the BKIN pin feeds the break");
    assert_eq!(bits(t(AF1), 9, 9), 0, "BKINP = 0: not inverted");
    assert_eq!(t(CR2) & (0x3F << 8), 0, "idle levels low");
    assert_eq!(sim.get(RCC_APB2ENR) & (1 << 11), 1 << 11, "TIM1EN");
    // The break configuration is written once, with its lock, after AF1 and CR2.
    let bdtr_w = sim.first_write(TIM1 + BDTR, |_| true).unwrap();
    assert!(
        sim.first_write(TIM1 + AF1, |_| true).unwrap() < bdtr_w
            && sim.first_write(TIM1 + CR2, |_| true).unwrap() < bdtr_w
    );
    // TIM1 is configured before its pins are handed to it.
    let pins_to_tim1 = sim
        .first_write(GPIOA + MODER, |v| bits(v, 17, 16) == 0b10)
        .unwrap();
    assert!(sim.first_write(TIM1 + CR1, |v| v & 1 == 1).unwrap() < pins_to_tim1);
}

/// DS12288 (STM32G474 datasheet) alternate-function table and RM0440 "General-purpose I/Os
/// (GPIO)" (MODER 10 = alternate function, PUPDR 01 up / 10 down): PWM on PA8/PA9 (AF6,
/// TIM1_CH1/CH2), the drive enable PA10 (AF6, TIM1_CH3) an output driven low until the drives
/// are enabled, the safe-torque-off input PB12 (AF6, TIM1_BKIN) pulled down, encoders on
/// PA6/PA7 (AF2, TIM3) and PB6/PB7 (AF2, TIM4) pulled up. PA6 (TIM1_BKIN on AF6) stays TIM3's.
#[test]
fn ds12288_pins_pwm_enable_break_and_encoders() {
    let sim = Sim::boot();
    for (port, n, af, mode, pull) in [
        (GPIOA, 8, 6, 0b10, 0b10),
        (GPIOA, 9, 6, 0b10, 0b10),
        (GPIOA, 10, 6, 0b01, 0b10),
        (GPIOB, 12, 6, 0b10, 0b10),
        (GPIOA, 6, 2, 0b10, 0b01),
        (GPIOA, 7, 2, 0b10, 0b01),
        (GPIOB, 6, 2, 0b10, 0b01),
        (GPIOB, 7, 2, 0b10, 0b01),
        (GPIOB, 1, 2, 0b10, 0b10),
        (GPIOB, 9, 2, 0b10, 0b10),
    ] {
        let name = format!("P{}{n}", if port == GPIOA { 'A' } else { 'B' });
        assert_eq!(pin_af(&sim, port, n), af, "{name} AF");
        assert_eq!(pin_mode(&sim, port, n), mode, "{name} mode");
        assert_eq!(pin_pull(&sim, port, n), pull, "{name} pull");
    }
    assert_eq!(sim.get(GPIOA + ODR) & (1 << 10), 0, "PA10 low");
    // The debug pins (PA13, PA14) keep their reset configuration.
    assert_eq!(sim.get(GPIOA + MODER) >> 26, 0xABFF_FFFF >> 26);
    assert_eq!(sim.get(RCC_AHB2ENR) & 0b11, 0b11, "GPIOA, GPIOB clocked");
}

/// RM0440 "General-purpose timers (TIM2/TIM3/TIM4/TIM5)", encoder interface mode: SMS = 0011
/// (bits 2:0 and 16) counts on both edges of TI1 and TI2, CC1S = CC2S = 01 map the inputs,
/// the full 16-bit range.
#[test]
fn rm0440_encoder_mode_3_on_tim3_and_tim4() {
    let sim = Sim::boot();
    for tim in [TIM3, TIM4] {
        let smcr = sim.get(tim + SMCR);
        assert_eq!(
            (bits(smcr, 2, 0), bits(smcr, 16, 16)),
            (0b011, 0),
            "SMS = encoder mode 3"
        );
        let ccmr1 = sim.get(tim + CCMR1);
        assert_eq!(
            (bits(ccmr1, 1, 0), bits(ccmr1, 9, 8)),
            (0b01, 0b01),
            "CC1S, CC2S = TI1, TI2"
        );
        assert_eq!(sim.get(tim + ARR), 0xFFFF);
        assert_eq!(sim.get(tim + CR1) & 1, 1, "counting");
        assert_eq!(
            sim.get(tim + CCER) & 0b1010_1010,
            0,
            "no inversion: the sign is a setting"
        );
        // The index: channel 4 an input capture on TI4 (CC4S = 01), enabled on the rising edge.
        let ccmr2 = sim.get(tim + 0x1C);
        assert_eq!(bits(ccmr2, 9, 8), 0b01, "CC4S = TI4");
        assert_eq!(
            bits(sim.get(tim + CCER), 15, 12),
            0b0001,
            "CC4E, rising edge"
        );
    }
    assert_eq!(sim.get(RCC_APB1ENR1) & 0b110, 0b110, "TIM3EN, TIM4EN");
}

/// RM0440 "Independent watchdog (IWDG)" (§42 in Rev 4): the software-start sequence (0xCCCC
/// starts it, 0x5555 unlocks PR and RLR, wait until SR is 0, 0xAAAA reloads) and
/// t = 4 · 2^PR · (RLR + 1) / f_LSI with a 12-bit RLR: 3 ms at the LSI's nominal 32 kHz, within
/// one count of the controller's stated timeout, and above the overrun streak's time even
/// with the LSI at its fastest.
#[test]
fn rm0440_42_iwdg_start_sequence_and_timeout() {
    let mut sim = Sim::at_reset();
    apply(&START_WATCHDOG, &mut sim).unwrap();
    let kr: Vec<u32> = sim
        .events
        .iter()
        .filter_map(|e| {
            if let Event::Write(IWDG_KR, v) = *e {
                Some(v)
            } else {
                None
            }
        })
        .collect();
    assert_eq!(kr, [0xCCCC, 0x5555, 0xAAAA]);
    let unlock = sim.first_write(IWDG_KR, |v| v == 0x5555).unwrap();
    let reload = sim.first_write(IWDG_KR, |v| v == 0xAAAA).unwrap();
    let pr_w = sim.first_write(IWDG_PR, |_| true).unwrap();
    let rlr_w = sim.first_write(IWDG_RLR, |_| true).unwrap();
    assert!(unlock < pr_w && unlock < rlr_w && pr_w < reload && rlr_w < reload);
    let sr_wait = START_WATCHDOG.iter().position(|s| {
        s.register.address == IWDG_SR
            && matches!(
                s.action,
                Action::WaitFor {
                    mask: 0b111,
                    value: 0,
                    ..
                }
            )
    });
    let reload_step = START_WATCHDOG
        .iter()
        .position(|s| s.action == Action::Write(0xAAAA));
    assert!(
        sr_wait.unwrap() < reload_step.unwrap(),
        "wait for the update before the reload"
    );
    let (pr, rlr) = (sim.get(IWDG_PR), sim.get(IWDG_RLR));
    assert!(pr <= 6 && rlr <= 0xFFF);
    let timeout_us = |lsi_hz: f64| (4u32 << pr) as f64 * (rlr + 1) as f64 / lsi_hz * 1e6;
    assert!(
        (timeout_us(32_000.0) - TIMEOUT_US as f64).abs() <= 125.0,
        "{}",
        timeout_us(32_000.0)
    );
    assert!(
        timeout_us(34_000.0) > MIN_TIMEOUT_US as f64,
        "{}",
        timeout_us(34_000.0)
    );
    assert!(timeout_us(29_500.0) < 3_500.0, "{}", timeout_us(29_500.0));
    assert!((plan::iwdg_timeout_us(32_000.0) as f64 - timeout_us(32_000.0)).abs() < 1e-3);
}

/// RM0440 "Debug support (DBG)", DBGMCU_CR (DBG_SLEEP bit 0), DBGMCU_APB1FZR1 (DBG_TIM6_STOP
/// bit 4, DBG_IWDG_STOP bit 12), DBGMCU_APB2FZR (DBG_TIM1_STOP bit 11); "Advanced-control
/// timers", debug mode: a frozen TIM1 disables its outputs as if MOE were reset. The encoder
/// timers (TIM3, TIM4: bits 1, 2) must keep counting while the core is halted.
#[test]
fn rm0440_debug_freeze_tim1_tim6_iwdg_not_the_encoders_and_debug_in_sleep() {
    let sim = Sim::boot();
    assert_eq!(sim.get(DBGMCU_CR) & 1, 1, "DBG_SLEEP");
    assert_eq!(sim.get(DBGMCU_APB2FZR) & (1 << 11), 1 << 11, "TIM1 frozen");
    let fz1 = sim.get(DBGMCU_APB1FZR1);
    assert_eq!(
        fz1 & ((1 << 4) | (1 << 12)),
        (1 << 4) | (1 << 12),
        "TIM6 and IWDG frozen"
    );
    assert_eq!(fz1 & 0b110, 0, "TIM3, TIM4 not frozen");
    // Frozen before TIM1 runs.
    assert!(
        sim.first_write(DBGMCU_APB2FZR, |_| true).unwrap()
            < sim.first_write(TIM1 + CR1, |v| v & 1 == 1).unwrap()
    );
}

/// RM0440 "Power control (PWR)", PWR_CR3 UCPD1_DBDIS (bit 14): the USB Type-C dead-battery
/// pull-downs on UCPD1_CC1 (PB6, encoder 1 channel A) and CC2 (PB4) are on from reset until it
/// is set; set before PB6 becomes an encoder input.
#[test]
fn rm0440_ucpd_dead_battery_pull_down_off_before_the_encoder_pin_is_used() {
    let sim = Sim::boot();
    assert_eq!(sim.get(PWR_CR3) & (1 << 14), 1 << 14);
    let dbdis = sim.first_write(PWR_CR3, |v| v & (1 << 14) != 0).unwrap();
    let pb6_af = sim
        .first_write(GPIOB + MODER, |v| bits(v, 13, 12) == 0b10)
        .unwrap();
    assert!(dbdis < pb6_af);
}

/// The safe state: both duties to zero torque (half of ARR) before TIM1's main output enable
/// is cleared, then the enable pin a GPIO output driven low. Enabling hands PA10 to TIM1 and
/// sets MOE. (RM0440 "Advanced-control timers": MOE gates every output; GPIO BSRR bit n + 16
/// resets pin n.)
#[test]
fn the_safe_state_returns_duty_to_zero_torque_then_drops_moe_and_drives_the_enable_low() {
    let mut sim = Sim::boot();
    apply(&ENABLE_OUTPUTS, &mut sim).unwrap();
    assert_eq!(sim.get(TIM1 + BDTR) & (1 << 15), 1 << 15, "MOE on");
    assert_eq!(pin_mode(&sim, GPIOA, 10), 0b10, "PA10 to TIM1_CH3");
    // The servo wrote some torque.
    sim.write(TIM1 + CCR1, 4000);
    sim.write(TIM1 + CCR2, 100);
    let start = sim.events.len();
    apply(&SAFE_STATE, &mut sim).unwrap();
    let events = &sim.events[start..];
    let at = |f: &dyn Fn(&Event) -> bool| events.iter().position(f).unwrap();
    let ccr1 = at(&|e| *e == Event::Write(TIM1 + CCR1, 2125));
    let ccr2 = at(&|e| *e == Event::Write(TIM1 + CCR2, 2125));
    let moe_off =
        at(&|e| matches!(*e, Event::Write(a, v) if a == TIM1 + BDTR && v & (1 << 15) == 0));
    assert!(
        ccr1 < moe_off && ccr2 < moe_off,
        "zero torque first, then outputs off"
    );
    assert_eq!(
        sim.get(TIM1 + BDTR) & !(1 << 15),
        g474_plan::plan::TIM1_BDTR,
        "the rest of BDTR written back unchanged"
    );
    assert_eq!(pin_mode(&sim, GPIOA, 10), 0b01);
    assert_eq!(sim.get(GPIOA + ODR) & (1 << 10), 0);
    // SAFE_STATE touches only registers (no waits): usable from fault handlers.
    assert!(SAFE_STATE
        .iter()
        .all(|s| matches!(s.action, Action::Write(_) | Action::Modify { .. })));
}

/// RM0440 "Reset and clock control (RCC)", RCC_CSR: LPWRRSTF 31, WWDGRSTF 30, IWDGRSTF 29,
/// SFTRSTF 28, BORRSTF 27, PINRSTF 26, OBLRSTF 25, RMVF 23. Internal resets also set PINRSTF.
#[test]
fn rm0440_rcc_csr_reset_cause() {
    let pin = 1 << 26;
    for (csr, cause) in [
        ((1 << 29) | pin, ResetCause::Watchdog),
        ((1 << 30) | pin, ResetCause::Watchdog),
        ((1 << 31) | pin, ResetCause::LowPower),
        ((1 << 27) | pin, ResetCause::PowerOnOrBrownOut),
        ((1 << 28) | pin, ResetCause::Software),
        ((1 << 25) | pin, ResetCause::OptionByteLoad),
        (pin, ResetCause::Pin),
        (0, ResetCause::Unknown),
    ] {
        assert_eq!(reset_cause(csr), cause, "{csr:#x}");
    }
    let mut sim = Sim::at_reset();
    apply(&plan::CLEAR_RESET_FLAGS, &mut sim).unwrap();
    assert_eq!(sim.get(RCC_CSR) & (1 << 23), 1 << 23, "RMVF");
}

/// Every step says why, and no two boot steps write the same register with the same value
/// (each write is meant: no copy left behind).
#[test]
fn every_step_says_why_and_the_boot_has_no_repeated_writes() {
    let all = BOOT
        .iter()
        .flat_map(|p| p.iter())
        .chain(START_WATCHDOG.iter())
        .chain(SAFE_STATE.iter())
        .chain(ENABLE_OUTPUTS.iter())
        .chain(HOST_LINK.iter());
    for s in all {
        assert!(s.why.len() >= 8, "{s:?}");
    }
    let writes: Vec<(u32, u32)> = BOOT
        .iter()
        .flat_map(|p| p.iter())
        .filter_map(|s| {
            if let Action::Write(v) = s.action {
                Some((s.register.address, v))
            } else {
                None
            }
        })
        .collect();
    for (k, w) in writes.iter().enumerate() {
        assert!(!writes[..k].contains(w), "{w:x?} written twice");
    }
}

/// The host link, LPUART1 at 115 200 Bd 8N1 on PA2/PA3 (the NUCLEO-G474RE's ST-LINK virtual COM
/// port). RM0440 "Low-power universal asynchronous receiver transmitter (LPUART)":
/// * "LPUART baud rate generation": baud = 256 · f_ck / LPUARTDIV (PRESC /1), LPUARTDIV at
///   least 0x300 and 20 bits wide, f_ck between 3 and 4096 times the baud rate;
/// * LPUART_CR1: UE bit 0, RE 2, TE 3, RXFNEIE 5, PCE 10 (no parity), M0 12 and M1 28 (00 =
///   8 data bits), FIFOEN 29 (writable only with UE = 0); LPUART_CR2 STOP bits 13:12 (00 = 1);
///   LPUART_CR3 RTSE 8, CTSE 9 (no flow control), DMAR 6, DMAT 7, OVRDIS 12 (0: an overrun is
///   flagged); ISR TEACK 21, REACK 22;
/// * "character transmission/reception procedure": the format and the baud rate before UE,
///   TE and RE after it.
///
/// "Reset and clock control (RCC)": RCC_APB1ENR2 LPUART1EN bit 0, RCC_CCIPR LPUART1SEL bits
/// 11:10 (00 = PCLK1), PCLK1 = 170 MHz with PPRE1 /1. DS12288 alternate functions: PA2 AF12 =
/// LPUART1_TX, PA3 AF12 = LPUART1_RX (AF7 is USART2, which the Nucleo does not route to the
/// ST-LINK).
#[test]
fn rm0440_lpuart1_host_link_at_115200_8n1_on_pa2_pa3_af12() {
    let mut sim = Sim::boot();
    let start = sim.events.len();
    apply(&HOST_LINK, &mut sim).unwrap();
    assert_eq!(sim.get(RCC_APB1ENR2) & 1, 1, "LPUART1EN");
    assert_eq!(bits(sim.get(RCC_CCIPR), 11, 10), 0b00, "LPUART1SEL = PCLK1");
    assert_eq!(
        bits(sim.get(RCC_CFGR), 10, 8) & 0b100,
        0,
        "PPRE1 /1: PCLK1 = HCLK"
    );
    let f_ck: u64 = 170_000_000;
    let (brr, presc) = (sim.get(LPUART1_BRR) as u64, sim.get(LPUART1_PRESC));
    assert_eq!(presc, 0, "kernel clock /1");
    assert!((0x300..=0xF_FFFF).contains(&brr), "LPUARTDIV {brr:#x}");
    assert!(
        (3 * 115_200..=4096 * 115_200).contains(&f_ck),
        "f_ck within 3 to 4096 times the baud rate"
    );
    let baud = 256.0 * f_ck as f64 / brr as f64;
    assert!((baud / 115_200.0 - 1.0).abs() < 1e-5, "{baud} Bd");
    assert_eq!(
        (brr, plan::LINK_BAUD, plan::LPUART1_BRR),
        (377_778, 115_200, 377_778)
    );
    let cr1 = sim.get(LPUART1_CR1);
    assert_eq!(
        (bits(cr1, 0, 0), bits(cr1, 2, 2), bits(cr1, 3, 3)),
        (1, 1, 1),
        "UE, RE, TE"
    );
    assert_eq!(
        bits(cr1, 5, 5),
        1,
        "RXFNEIE: the receive interrupt (LINK_RX)"
    );
    assert_eq!(bits(cr1, 29, 29), 1, "FIFOEN");
    assert_eq!(
        (bits(cr1, 12, 12), bits(cr1, 28, 28), bits(cr1, 10, 10)),
        (0, 0, 0),
        "8 data bits, no parity"
    );
    assert_eq!(
        cr1 & ((1 << 4) | (1 << 6) | (1 << 7) | (1 << 8)),
        0,
        "no IDLE, TC, TXE or PE interrupt"
    );
    assert_eq!(bits(sim.get(LPUART1_CR2), 13, 12), 0, "1 stop bit");
    let cr3 = sim.get(LPUART1_CR3);
    assert_eq!(
        cr3 & ((1 << 6) | (1 << 7) | (1 << 8) | (1 << 9) | (1 << 12)),
        0,
        "no DMA, no flow control, overruns flagged"
    );
    // Order: clock, then format and baud with UE = 0, then UE, then TE/RE, then the pins.
    let events = &sim.events[start..];
    let at = |f: &dyn Fn(u32, u32) -> bool| {
        events
            .iter()
            .position(|e| matches!(*e, Event::Write(a, v) if f(a, v)))
            .unwrap()
    };
    let clock = at(&|a, v| a == RCC_APB1ENR2 && v & 1 == 1);
    let first_uart = at(&|a, _| (LPUART1..LPUART1 + 0x400).contains(&a));
    let fifoen = at(&|a, v| a == LPUART1_CR1 && v & (1 << 29) != 0);
    let brr_w = at(&|a, _| a == LPUART1_BRR);
    let ue = at(&|a, v| a == LPUART1_CR1 && v & 1 == 1);
    let te_re = at(&|a, v| a == LPUART1_CR1 && v & 0b1100 == 0b1100);
    assert!(clock < first_uart && fifoen < ue && brr_w < ue && ue <= te_re);
    assert_eq!(
        events
            .iter()
            .filter(|e| matches!(**e, Event::Write(LPUART1_CR1, v) if v & 1 == 0))
            .count(),
        1,
        "UE = 0 while configuring"
    );
    for (n, name) in [(2, "PA2"), (3, "PA3")] {
        assert_eq!(pin_af(&sim, GPIOA, n), 12, "{name} AF12");
        assert_eq!(pin_mode(&sim, GPIOA, n), 0b10, "{name} alternate function");
        let to_uart = at(&|a, v| a == GPIOA + MODER && bits(v, 2 * n + 1, 2 * n) == 0b10);
        assert!(te_re < to_uart, "{name} handed over after the LPUART is on");
    }
    assert_eq!(pin_pull(&sim, GPIOA, 3), 0b01, "RX pulled up");
    // The link takes no pin of the drives, the break or the encoders (they keep the boot's).
    let boot = Sim::boot();
    for (port, n) in [
        (GPIOA, 6),
        (GPIOA, 7),
        (GPIOA, 8),
        (GPIOA, 9),
        (GPIOA, 10),
        (GPIOB, 12),
    ] {
        assert_eq!(
            (pin_mode(&sim, port, n), pin_af(&sim, port, n)),
            (pin_mode(&boot, port, n), pin_af(&boot, port, n)),
            "pin {port:#x}/{n}"
        );
    }
}

/// An LPUART that never acknowledges its transmitter (its clock is not running) stops the
/// link's plan at that wait, before PA2 is handed to it: the pin stays as it was at reset
/// (analog), nothing is driven onto the ST-LINK's line.
#[test]
fn a_link_uart_that_does_not_acknowledge_leaves_its_pins_alone() {
    let mut sim = Sim::boot();
    sim.lpuart_acks = false;
    let failed = apply(&HOST_LINK, &mut sim).unwrap_err();
    assert_eq!(failed.register.address, LPUART1_ISR);
    assert_eq!(
        (pin_mode(&sim, GPIOA, 2), pin_mode(&sim, GPIOA, 3)),
        (0b11, 0b11)
    );
}
