//! The host link's byte port on LPUART1 (configured by [`crate::plan::HOST_LINK`]): what the
//! board's `LinkPort` does with the registers, over [`Bus`] so that `cargo test` runs the same
//! code against a simulated LPUART (`tests/link_uart.rs`).
//!
//! Who calls it: only the app's link task (priority 1, on LPUART1's interrupt `LINK_RX`, and
//! pended by the servo task every 5 ms). The servo task (priority 3) never touches the UART
//! and preempts all of this, so nothing here can delay it; every loop is bounded.
//!
//! * **Receive**: the LPUART's 8-byte RX FIFO is moved into a software ring of
//!   [`RX_RING_LEN`] bytes ([`LinkUart::pump`]) by every read, and also while a write waits
//!   for room in the TX FIFO. So a reply that takes milliseconds to go out at 115 200 Bd loses
//!   none of the bytes the host sends meanwhile (the garbage test sends 300-byte bursts; the
//!   requests are one at a time otherwise). A full ring drops the byte and counts it.
//! * **Errors**: an overrun (ORE: a byte came with the RX FIFO full, e.g. while the link task
//!   was held off by a long flash erase) and the line errors (framing, noise, parity) are
//!   cleared in ICR and counted, and reading goes on: ORE also raises the receive interrupt,
//!   so an uncleared one would re-enter the link task forever. The damaged frame fails its CRC
//!   or COBS check and the controller answers it with a rejection (`link-protocol`).
//! * **Transmit**: a byte is written when the TX FIFO has room; a FIFO that stays full for
//!   [`TX_PATIENCE_POLLS`] polls (far longer than a byte takes: only a stopped clock does that)
//!   drops the rest of the write and counts it, so a dead transmitter cannot stall the link
//!   task.
use heapless::Deque;

use crate::map::lpuart;
use crate::Bus;

/// The receive ring's length (bytes): 44 ms of back-to-back bytes at 115 200 Bd, more than
/// the longest burst the host tool sends without waiting for an answer (300 bytes).
pub const RX_RING_LEN: usize = 512;
/// Polls of a full TX FIFO before a byte is dropped (a byte takes about 1 500 polls at
/// 115 200 Bd and 170 MHz: one poll is a few APB reads).
pub const TX_PATIENCE_POLLS: u32 = 200_000;
/// Most RX FIFO entries one [`LinkUart::pump`] moves (twice the FIFO's 8, so that a receive
/// flag stuck by a hardware fault cannot keep a pump going).
const PUMP_LIMIT: u32 = 16;

/// What the port counts (the board logs them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkUartCounts {
    /// Overruns (ORE): at least one byte lost each.
    pub overruns: u32,
    /// Bytes received with a framing, noise or parity error (kept: the frame check rejects them).
    pub line_errors: u32,
    /// Bytes dropped because the receive ring was full.
    pub rx_dropped: u32,
    /// Bytes not sent because the TX FIFO stayed full.
    pub tx_dropped: u32,
}

/// LPUART1 as the host link's port: the receive ring and the counters.
pub struct LinkUart {
    rx: Deque<u8, RX_RING_LEN>,
    counts: LinkUartCounts,
}

impl Default for LinkUart {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkUart {
    /// An empty ring (the LPUART itself is configured by [`crate::plan::HOST_LINK`]).
    pub const fn new() -> Self {
        LinkUart {
            rx: Deque::new(),
            counts: LinkUartCounts {
                overruns: 0,
                line_errors: 0,
                rx_dropped: 0,
                tx_dropped: 0,
            },
        }
    }

    /// The counters so far.
    pub fn counts(&self) -> LinkUartCounts {
        self.counts
    }

    /// Moves what the RX FIFO holds into the ring, clearing and counting the error flags.
    pub fn pump<B: Bus>(&mut self, bus: &mut B) {
        for _ in 0..PUMP_LIMIT {
            let isr = bus.read(lpuart::ISR.address);
            let errors = isr & lpuart::ICR_ERRORS;
            if errors != 0 {
                if errors & lpuart::ISR_ORE != 0 {
                    self.counts.overruns = self.counts.overruns.wrapping_add(1);
                }
                if errors & !lpuart::ISR_ORE != 0 {
                    self.counts.line_errors = self.counts.line_errors.wrapping_add(1);
                }
                bus.write(lpuart::ICR.address, errors);
            }
            if isr & lpuart::ISR_RXFNE == 0 {
                return;
            }
            let byte = bus.read(lpuart::RDR.address) as u8;
            if self.rx.push_back(byte).is_err() {
                self.counts.rx_dropped = self.counts.rx_dropped.wrapping_add(1);
            }
        }
    }

    /// The next received byte, if any (pumps the RX FIFO first).
    pub fn read_byte<B: Bus>(&mut self, bus: &mut B) -> Option<u8> {
        self.pump(bus);
        self.rx.pop_front()
    }

    /// Writes `bytes` through the TX FIFO, receiving meanwhile. If the FIFO has no room
    /// within [`TX_PATIENCE_POLLS`] polls, that byte and the rest of `bytes` are dropped and
    /// counted (the transmitter is dead: waiting for each byte again would hold the link task
    /// for seconds).
    pub fn write<B: Bus>(&mut self, bus: &mut B, bytes: &[u8]) {
        for (k, &b) in bytes.iter().enumerate() {
            let mut patience = TX_PATIENCE_POLLS;
            while bus.read(lpuart::ISR.address) & lpuart::ISR_TXFNF == 0 {
                if patience == 0 {
                    let left = (bytes.len() - k) as u32;
                    self.counts.tx_dropped = self.counts.tx_dropped.wrapping_add(left);
                    return;
                }
                self.pump(bus);
                patience -= 1;
            }
            bus.write(lpuart::TDR.address, u32::from(b));
        }
        self.pump(bus);
    }
}
