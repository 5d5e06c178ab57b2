//! The same-core check's MCU side: runs `tests/golden/cases.rs` (IK, FK, Jacobian, grid
//! lookups, a closed servo sequence) on the Cortex-M4F and prints every result as
//! `GOLDEN <hex>`; `tests/tests/same_core_on_mcu.rs` runs this under QEMU and requires the
//! host's results, from the same source, to be bit-identical. QEMU board only.
#![no_std]
#![no_main]

use core::fmt::Write;

use cortex_m_rt::entry;
use firmware::board;

mod cases {
    include!("../../../tests/golden/cases.rs");
}

#[entry]
fn main() -> ! {
    let mut count: u32 = 0;
    cases::run(&mut |word| {
        let mut line: heapless::String<24> = heapless::String::new();
        let _ = write!(line, "GOLDEN {word:08x}");
        board::console(&line);
        count += 1;
    });
    let mut line: heapless::String<32> = heapless::String::new();
    let _ = write!(line, "GOLDEN-END {count}");
    board::console(&line);
    board::exit(true)
}
