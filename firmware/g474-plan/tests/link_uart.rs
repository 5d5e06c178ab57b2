//! The host link's LPUART1 port (`g474_plan::link_uart`) against a simulated LPUART in FIFO
//! mode (RM0440 "Low-power universal asynchronous receiver transmitter (LPUART)": 8-byte RX
//! and TX FIFOs; ISR RXFNE bit 5, TXFNF bit 7, ORE bit 3 set when a character arrives with the
//! RX FIFO full (the character is lost), FE bit 1; ICR clears a flag by writing 1 at its
//! position; reading RDR pops the RX FIFO, writing TDR pushes the TX FIFO).
//!
//! Time in the simulation advances with every ISR read (the driver polls ISR): every
//! `byte_reads` of them one character arrives from the host and one leaves the TX FIFO, so
//! the driver meets the hardware's pace, not an idealised one.
use std::collections::VecDeque;

use g474_plan::link_uart::{LinkUart, LinkUartCounts, RX_RING_LEN, TX_PATIENCE_POLLS};
use g474_plan::Bus;

const LPUART1: u32 = 0x4000_8000;
const ISR: u32 = LPUART1 + 0x1C;
const ICR: u32 = LPUART1 + 0x20;
const RDR: u32 = LPUART1 + 0x24;
const TDR: u32 = LPUART1 + 0x28;
const FE: u32 = 1 << 1;
const ORE: u32 = 1 << 3;
const RXFNE: u32 = 1 << 5;
const TXFNF: u32 = 1 << 7;
const FIFO: usize = 8;

struct Lpuart {
    /// What the host has yet to send, one character per `byte_reads` ISR reads.
    incoming: VecDeque<u8>,
    rx_fifo: VecDeque<u8>,
    tx_fifo: VecDeque<u8>,
    /// What went out on the wire.
    sent: Vec<u8>,
    flags: u32,
    byte_reads: u32,
    isr_reads: u32,
    /// The transmitter's clock runs (a dead one never drains its FIFO).
    tx_alive: bool,
    /// Every received byte reads with the receive flag set (a stuck flag).
    rx_stuck: bool,
    /// Bytes lost to overruns.
    lost: usize,
}

impl Lpuart {
    fn new(incoming: &[u8], byte_reads: u32) -> Self {
        Lpuart {
            incoming: incoming.iter().copied().collect(),
            rx_fifo: VecDeque::new(),
            tx_fifo: VecDeque::new(),
            sent: Vec::new(),
            flags: 0,
            byte_reads,
            isr_reads: 0,
            tx_alive: true,
            rx_stuck: false,
            lost: 0,
        }
    }

    /// One character time passes.
    fn tick(&mut self) {
        if let Some(b) = self.incoming.pop_front() {
            if self.rx_fifo.len() == FIFO {
                self.flags |= ORE;
                self.lost += 1;
            } else {
                self.rx_fifo.push_back(b);
            }
        }
        if self.tx_alive {
            if let Some(b) = self.tx_fifo.pop_front() {
                self.sent.push(b);
            }
        }
    }
}

impl Bus for Lpuart {
    fn read(&mut self, address: u32) -> u32 {
        match address {
            ISR => {
                self.isr_reads += 1;
                if self.isr_reads % self.byte_reads == 0 {
                    self.tick();
                }
                let rx = if !self.rx_fifo.is_empty() || self.rx_stuck {
                    RXFNE
                } else {
                    0
                };
                let tx = if self.tx_fifo.len() < FIFO { TXFNF } else { 0 };
                self.flags | rx | tx
            }
            RDR => u32::from(self.rx_fifo.pop_front().unwrap_or(0xEE)),
            _ => panic!("read of {address:#x}"),
        }
    }
    fn write(&mut self, address: u32, value: u32) {
        match address {
            ICR => self.flags &= !value,
            TDR => {
                assert!(
                    self.tx_fifo.len() < FIFO,
                    "TDR written with the TX FIFO full"
                );
                self.tx_fifo.push_back(value as u8);
            }
            _ => panic!("write of {address:#x}"),
        }
    }
    fn delay(&mut self, _: u32) {}
}

fn drain(port: &mut LinkUart, bus: &mut Lpuart) -> Vec<u8> {
    let mut got = Vec::new();
    while let Some(b) = port.read_byte(bus) {
        got.push(b);
    }
    got
}

/// A long reply goes out at the line's pace while the host keeps sending: without receiving
/// during the write, the 8-byte RX FIFO would overrun after 8 characters.
#[test]
fn bytes_arriving_while_a_reply_goes_out_are_all_kept_in_order() {
    let request: Vec<u8> = (0..300u32).map(|k| (k * 7 + 1) as u8).collect();
    let reply: Vec<u8> = (0..200u32).map(|k| (k * 3) as u8).collect();
    let mut bus = Lpuart::new(&request, 10);
    let mut port = LinkUart::new();
    port.write(&mut bus, &reply);
    // The rest of the request arrives after the reply was queued.
    let mut got = drain(&mut port, &mut bus);
    while !bus.incoming.is_empty() || !bus.rx_fifo.is_empty() {
        for _ in 0..10 {
            bus.read(ISR);
        }
        got.extend(drain(&mut port, &mut bus));
    }
    assert_eq!(got, request);
    while !bus.tx_fifo.is_empty() {
        bus.read(ISR);
    }
    assert_eq!(bus.sent, reply);
    assert_eq!(port.counts(), LinkUartCounts::default());
    assert_eq!(bus.lost, 0);
}

/// The link task was held off (e.g. by a flash erase) while the host sent: the FIFO is full,
/// later characters were lost, ORE is set. Reading returns what the FIFO kept, clears ORE
/// (otherwise its interrupt would re-enter the link task forever), counts it, and ends.
#[test]
fn an_overrun_is_cleared_counted_and_reading_goes_on() {
    let sent: Vec<u8> = (1..=12).collect();
    let mut bus = Lpuart::new(&sent, 1);
    for _ in 0..12 {
        bus.tick();
    }
    assert_eq!((bus.rx_fifo.len(), bus.lost, bus.flags & ORE), (8, 4, ORE));
    let mut port = LinkUart::new();
    assert_eq!(drain(&mut port, &mut bus), (1..=8).collect::<Vec<u8>>());
    assert_eq!(bus.flags & ORE, 0, "ORE cleared");
    assert_eq!(port.counts().overruns, 1);
    assert_eq!(port.read_byte(&mut bus), None);
    // Reception goes on normally after it.
    bus.incoming.extend([0xA5, 0x5A]);
    bus.tick();
    bus.tick();
    assert_eq!(drain(&mut port, &mut bus), [0xA5, 0x5A]);
    assert_eq!(port.counts().overruns, 1);
}

/// A framing error (a noisy or unplugged line) keeps the byte for the frame check to reject,
/// clears the flag and counts it.
#[test]
fn a_framing_error_is_cleared_and_counted_and_its_byte_kept() {
    let mut bus = Lpuart::new(&[0x42], 1);
    bus.tick();
    bus.flags |= FE;
    let mut port = LinkUart::new();
    assert_eq!(drain(&mut port, &mut bus), [0x42]);
    assert_eq!(bus.flags, 0);
    assert_eq!(port.counts().line_errors, 1);
}

/// A transmitter that never drains (its clock stopped): the write gives up after its patience
/// for the first byte that finds no room and drops the rest, instead of waiting for each.
#[test]
fn a_dead_transmitter_drops_the_write_and_returns() {
    let mut bus = Lpuart::new(&[], 1);
    bus.tx_alive = false;
    let mut port = LinkUart::new();
    port.write(&mut bus, &[7; 100]);
    assert_eq!(bus.tx_fifo.len(), FIFO, "the FIFO took 8");
    assert_eq!(port.counts().tx_dropped, 92);
    assert!(
        bus.isr_reads < 3 * TX_PATIENCE_POLLS + 1_000,
        "{} ISR reads",
        bus.isr_reads
    );
}

/// More than the ring holds, never read: the excess is dropped and counted, the oldest kept.
#[test]
fn a_full_receive_ring_drops_and_counts_the_excess() {
    let sent: Vec<u8> = (0..RX_RING_LEN + 88).map(|k| k as u8).collect();
    let mut bus = Lpuart::new(&sent, 1);
    let mut port = LinkUart::new();
    while !bus.incoming.is_empty() || !bus.rx_fifo.is_empty() {
        port.pump(&mut bus);
    }
    assert_eq!(port.counts().rx_dropped, 88);
    assert_eq!(drain(&mut port, &mut bus), sent[..RX_RING_LEN]);
}

/// A receive flag stuck by a hardware fault cannot keep one pump going: it takes at most 16
/// bytes (twice the FIFO) per call, so the link task's caller decides when to stop.
#[test]
fn a_stuck_receive_flag_cannot_keep_a_pump_going() {
    let mut bus = Lpuart::new(&[], 1_000_000);
    bus.rx_stuck = true;
    let mut port = LinkUart::new();
    port.pump(&mut bus);
    assert_eq!(bus.isr_reads, 16);
}
