//! The driver wrapper: a board's Ethernet driver behind the ports' gates ([`Backlogged`]), and
//! the keyed initial sequence numbers of every TCP connection ([`crate::isn`]).

use core::future::Future;
use core::pin::Pin;
use core::task::Context;

use embassy_net_driver::{Capabilities, Checksum, Driver, HardwareAddress, LinkState, RxToken, TxToken};

use super::frame::destination_port;
use super::gate::Gate;
use super::queue::{Verdict, MAX_SYN_FRAME};
use crate::isn::{self, IsnKey};

use embassy_time::{Instant, Timer};

fn now_ms() -> u64 {
    Instant::now().as_millis()
}

/// A board's Ethernet driver behind the ports' backlogs ([`GATES`](super::GATES)): every
/// received frame is seen by the gates first; a held SYN reaches the stack later, from
/// its gate's copy. Every TCP segment, sent or received, has its sequence numbers moved by
/// the connection's keyed offset ([`crate::isn`]: RFC 6528's ISNs on a stack that has none).
pub struct Backlogged<D> {
    inner: D,
    gates: &'static [&'static dyn Gate],
    released: [u8; MAX_SYN_FRAME],
    key: IsnKey,
    /// Whether the stack computes the TCP checksum of what it sends: it is corrected then; with
    /// offload the hardware fills it in after.
    checksum: bool,
}

impl<D: Driver> Backlogged<D> {
    /// `inner` behind `gates`; `isn_key` from the board's entropy (a board without one says so).
    pub fn new(inner: D, gates: &'static [&'static dyn Gate], isn_key: [u8; 16]) -> Self {
        let checksum = matches!(inner.capabilities().checksum.tcp, Checksum::Both | Checksum::Tx);
        Self { inner, gates, released: [0; MAX_SYN_FRAME], key: IsnKey::new(isn_key), checksum }
    }
}

/// A transmit token of [`Backlogged`]: the frame as the stack wrote it, with the keyed ISN's
/// offset added to a TCP segment's sequence number.
pub struct Tx<T> {
    inner: T,
    key: IsnKey,
    checksum: bool,
}

impl<T: TxToken> TxToken for Tx<T> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
        let Tx { inner, key, checksum } = self;
        inner.consume(len, |frame| {
            let result = f(frame);
            isn::outgoing(&key, frame, checksum);
            result
        })
    }
}

/// What the gates make of a frame: the first gate of its destination port decides (one
/// gate for a port, even were two services set to the same one); other frames pass.
fn arrive(gates: &[&dyn Gate], frame: &[u8], now_ms: u64) -> Verdict {
    let Some(port) = destination_port(frame) else { return Verdict::Pass };
    gates.iter().find(|gate| gate.port() == port).map_or(Verdict::Pass, |gate| gate.arrive(frame, now_ms))
}

/// A received frame: the driver's own (the gate looks at it as the stack takes it), or a
/// held SYN the gate released; the keyed ISN's offset taken off a TCP segment's
/// acknowledgment before the stack sees it.
pub enum Rx<'a, T> {
    /// From the driver.
    Wire(T, &'static [&'static dyn Gate], IsnKey),
    /// A released SYN.
    Released(&'a mut [u8], IsnKey),
}

impl<T: RxToken> RxToken for Rx<'_, T> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
        match self {
            Rx::Wire(token, gates, key) => token.consume(|frame| match arrive(gates, frame, now_ms()) {
                Verdict::Pass => {
                    isn::incoming(&key, frame);
                    f(frame)
                }
                // The stack drops an empty frame (too short for Ethernet) without a word.
                Verdict::Hold => f(&mut []),
            }),
            Rx::Released(frame, key) => {
                isn::incoming(&key, frame);
                f(frame)
            }
        }
    }
}

impl<D: Driver> Driver for Backlogged<D> {
    type RxToken<'a>
        = Rx<'a, D::RxToken<'a>>
    where
        Self: 'a;
    type TxToken<'a>
        = Tx<D::TxToken<'a>>
    where
        Self: 'a;

    fn receive(&mut self, cx: &mut Context) -> Option<(Self::RxToken<'_>, Self::TxToken<'_>)> {
        // Held SYNs first, in order, whenever a task listens for them (and the driver can
        // send the answer).
        let now = now_ms();
        let mut next: Option<u64> = None;
        for gate in self.gates {
            match gate.ready(now, cx) {
                Ok(()) => {
                    // The answer needs a transmit buffer: without one, the SYN stays held
                    // (the driver wakes the runner when one frees). `release` cannot fail
                    // after `ready` (nothing runs between).
                    let tx = Tx { inner: self.inner.transmit(cx)?, key: self.key, checksum: self.checksum };
                    let len = gate.release(now, &mut self.released)?;
                    return Some((Rx::Released(&mut self.released[..len], self.key), tx));
                }
                Err(Some(at)) => next = Some(next.map_or(at, |n| n.min(at))),
                Err(None) => {}
            }
        }
        // SYNs wait; nothing may wake the runner when one lapses: a timer does.
        if let Some(at) = next {
            let mut timer = Timer::at(Instant::from_millis(at));
            let _ = Pin::new(&mut timer).poll(cx);
        }
        let (rx, tx) = self.inner.receive(cx)?;
        let tx = Tx { inner: tx, key: self.key, checksum: self.checksum };
        Some((Rx::Wire(rx, self.gates, self.key), tx))
    }

    fn transmit(&mut self, cx: &mut Context) -> Option<Self::TxToken<'_>> {
        let tx = self.inner.transmit(cx)?;
        Some(Tx { inner: tx, key: self.key, checksum: self.checksum })
    }

    fn link_state(&mut self, cx: &mut Context) -> LinkState {
        self.inner.link_state(cx)
    }

    fn capabilities(&self) -> Capabilities {
        self.inner.capabilities()
    }

    fn hardware_address(&self) -> HardwareAddress {
        self.inner.hardware_address()
    }
}
