//! A listen backlog for the Modbus/TCP port (and the web console's, feature `web`), for a TCP
//! stack that has none (smoltcp).
//!
//! smoltcp gives each connection a socket of its own and answers a SYN that finds no socket
//! listening with a RST. Under a flood (64 clients connecting at once, spec §1.1's newcomer
//! behind them), the connection tasks' listening sockets are taken by the flood's first SYNs
//! within microseconds, and every later SYN, the newcomer's among them, is refused before an
//! evicted task can listen again. A capture under QEMU showed exactly that: 65 SYNs in 1.4 ms,
//! 9 SYN-ACKs, 56 RSTs.
//!
//! The backlog sits between the Ethernet driver and the stack ([`Backlogged`], one wrapper for
//! every board's driver). A SYN for the Modbus port goes through to the stack only while a
//! connection task is listening for it; otherwise the frame is held (up to [`HELD`], in
//! arrival order) and given to the stack as soon as a task listens again, so each newcomer is
//! accepted, and spec §1.1's eviction (the connection idle longest) makes room, as a backlog on
//! a desktop TCP stack would. The tasks say when they listen and when they have accepted
//! ([`SynGate::listening`], [`SynGate::accepted`]); the gate counts the SYNs it let through
//! whose handshakes are under way, so it never lets through more than the tasks can take.
//!
//! Bounds: a held SYN older than [`HOLD_MS`] is dropped (its client sends it again after its
//! retransmission timeout, 1 s on Linux and Windows); when the backlog is full the oldest held
//! SYN is dropped for the new one (a newcomer is never the one refused). A SYN let through
//! counts until its task accepts, its client resets the handshake, or [`HANDSHAKE_MS`] passes:
//! the connection tasks give a handshake [`HANDSHAKE_TIMEOUT_MS`] (smoltcp has no limit of its
//! own, and a SYN from a host that went away would hold a task for ever), then listen again.
//! A SYN sent again while its handshake is under way is dropped: the socket in SYN-RECEIVED
//! sends its SYN-ACK again on its own timer, and a second listening socket taking the copy
//! would reset the client when its ACK reached the first.

use core::cell::RefCell;
use core::task::{Context, Waker};

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use heapless::{Deque, Vec};

use remodaq_shared::sockets::MODBUS_SOCKETS as SOCKETS;

/// SYN frames held at most.
pub const HELD: usize = 64;
/// The longest SYN frame held: Ethernet (14) + IPv4 without options (20) + TCP with the full 40
/// bytes of options (60) + the frame check sequence (4), which some MACs hand over with the
/// frame: the STM32's ETH_MACCR APCS strips it only from frames whose length/type field is
/// at most 1500, and embassy-stm32 leaves CSTF (bit 25, stripping for type frames such as
/// IPv4) clear. A longer one (IP options) goes to the stack at once.
pub const MAX_SYN_FRAME: usize = 98;
/// A held SYN is dropped after this long (ms).
pub const HOLD_MS: u64 = 1000;
/// How long a connection task waits for a handshake it has answered (ms): smoltcp's first
/// SYN-ACK retransmission comes after 1 s, a second after 3 s in all.
pub const HANDSHAKE_TIMEOUT_MS: u64 = 4000;
/// A SYN let through counts against the listening tasks for at most this long (ms): longer
/// than a task's wait for its handshake.
pub const HANDSHAKE_MS: u64 = HANDSHAKE_TIMEOUT_MS + 1000;

/// A TCP client: IPv4 address and port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Peer {
    /// IPv4 address.
    pub ip: [u8; 4],
    /// TCP port.
    pub port: u16,
}

/// The client of `frame` if it is an Ethernet II frame carrying an IPv4 TCP segment to
/// `port` with SYN set and ACK, RST and FIN clear (a connection request, RFC 9293 §3.5);
/// `None` for anything else, a fragment or a truncated frame included.
pub fn syn_to(frame: &[u8], port: u16) -> Option<Peer> {
    let (peer, flags) = segment_to(frame, port)?;
    (flags & (SYN | ACK | RST | FIN) == SYN).then_some(peer)
}

/// TCP flags (RFC 9293 §3.1).
const FIN: u8 = 0x01;
const SYN: u8 = 0x02;
const RST: u8 = 0x04;
const ACK: u8 = 0x10;

/// The client and TCP flags of `frame` if it is an Ethernet II frame carrying a whole IPv4 TCP
/// segment to `port`.
fn segment_to(frame: &[u8], port: u16) -> Option<(Peer, u8)> {
    let (peer, destination, flags) = segment(frame)?;
    (destination == port).then_some((peer, flags))
}

/// The destination port of `frame` if it is an Ethernet II frame carrying a whole IPv4 TCP
/// segment.
pub fn destination_port(frame: &[u8]) -> Option<u16> {
    segment(frame).map(|(_, port, _)| port)
}

/// The client, destination port and TCP flags of `frame` if it is an Ethernet II frame carrying
/// a whole IPv4 TCP segment.
fn segment(frame: &[u8]) -> Option<(Peer, u16, u8)> {
    // Ethernet II: destination (6), source (6), EtherType (2) = 0x0800 IPv4.
    let ip = frame.get(14..).filter(|_| frame.get(12..14) == Some(&[0x08, 0x00]))?;
    // IPv4 (RFC 791): version 4, IHL in 32-bit words (at least 5), protocol 6 = TCP, and not
    // a fragment past the first (fragment offset 0; a first fragment with MF is not a whole
    // segment either).
    let (&version_ihl, _) = ip.split_first()?;
    let ihl = usize::from(version_ihl & 0x0F) * 4;
    if version_ihl >> 4 != 4 || ihl < 20 || *ip.get(9)? != 6 {
        return None;
    }
    let flags_offset = u16::from_be_bytes([*ip.get(6)?, *ip.get(7)?]);
    if flags_offset & 0x3FFF != 0 {
        return None;
    }
    let source = [*ip.get(12)?, *ip.get(13)?, *ip.get(14)?, *ip.get(15)?];
    // TCP (RFC 9293 §3.1): source port, destination port, ..., flags at byte 13.
    let tcp = ip.get(ihl..)?;
    let source_port = u16::from_be_bytes([*tcp.first()?, *tcp.get(1)?]);
    let destination_port = u16::from_be_bytes([*tcp.get(2)?, *tcp.get(3)?]);
    let flags = *tcp.get(13)?;
    Some((Peer { ip: source, port: source_port }, destination_port, flags))
}

/// SYNs one source address may have held at once: its newest replaces its oldest.
pub const HELD_PER_SOURCE: usize = 4;

/// The RFC 1071 ones'-complement sum of `parts` (as one byte string), folded to 16 bits.
fn ones_sum(parts: &[&[u8]]) -> u16 {
    let mut sum = 0u32;
    let mut odd: Option<u8> = None;
    for part in parts {
        for &byte in *part {
            match odd.take() {
                Some(high) => sum += u32::from(u16::from_be_bytes([high, byte])),
                None => odd = Some(byte),
            }
        }
    }
    if let Some(high) = odd {
        sum += u32::from(u16::from_be_bytes([high, 0]));
    }
    while sum > 0xFFFF {
        sum = (sum & 0xFFFF) + (sum >> 16);
    }
    sum as u16
}

/// Whether a TCP/IPv4 frame is for the module with `mac` and `ip` and intact: the destination
/// MAC and IP are the module's, and the IPv4 header checksum (RFC 791 §3.1) and the TCP
/// checksum over its pseudo-header (RFC 9293 §3.1) are right. (A checksum field of 0 is a
/// checksum like any other for TCP: RFC 9293 makes it mandatory.)
pub fn for_me(frame: &[u8], mac: &[u8; 6], ip: &[u8; 4]) -> bool {
    let check = || -> Option<bool> {
        let packet = frame.get(14..)?;
        let ihl = usize::from(packet.first()? & 0x0F) * 4;
        let total = usize::from(u16::from_be_bytes([*packet.get(2)?, *packet.get(3)?]));
        let header = packet.get(..ihl)?;
        let segment = packet.get(ihl..total)?;
        let (source, destination) = (header.get(12..16)?, header.get(16..20)?);
        let length = (segment.len() as u16).to_be_bytes();
        Some(
            frame.get(..6)? == mac
                && destination == ip
                && ones_sum(&[header]) == 0xFFFF
                && ones_sum(&[source, destination, &[0, 6], &length, segment]) == 0xFFFF,
        )
    };
    check().unwrap_or(false)
}

/// What becomes of a received frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// To the stack now.
    Pass,
    /// Kept in the backlog (or dropped: a repeat of a SYN already held); the stack gets nothing.
    Hold,
}

struct HeldSyn {
    peer: Peer,
    at_ms: u64,
    len: usize,
    frame: [u8; MAX_SYN_FRAME],
}

/// The backlog's state: plain logic over a millisecond clock the caller passes in. `H`: SYNs
/// held at most; `S`: connection tasks on the port at most.
pub struct Backlog<const H: usize, const S: usize> {
    port: u16,
    /// Connection tasks listening on `port` (or in a handshake they have not finished).
    accepting: usize,
    /// SYNs let through whose handshakes are under way, and when.
    in_flight: Vec<(Peer, u64), S>,
    held: Deque<HeldSyn, H>,
    /// The module's MAC and IPv4 address, once the board said: SYNs for anything else, or
    /// damaged, are dropped before they can take a listening task's place.
    me: Option<([u8; 6], [u8; 4])>,
    /// SYNs one source address may have held (`None`: `H`, until the board says otherwise).
    /// `None` rather than `H` keeps a new backlog all zeros, so that its static goes to .bss
    /// instead of taking its size in flash too (.data: 8.9 KB for the two ports' backlogs).
    per_source: Option<core::num::NonZeroUsize>,
}

/// The Modbus port's backlog: [`HELD`] SYNs, the server's [`SOCKETS`] connection tasks.
pub type ModbusBacklog = Backlog<HELD, SOCKETS>;

impl<const H: usize, const S: usize> Default for Backlog<H, S> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const H: usize, const S: usize> Backlog<H, S> {
    /// Empty, no task listening.
    pub const fn new() -> Self {
        Self { port: 0, accepting: 0, in_flight: Vec::new(), held: Deque::new(), me: None, per_source: None }
    }

    /// The module's MAC and IPv4 address: from now on only SYNs to them, with right checksums,
    /// count.
    /// `per_source`: SYNs one source address may have held ([`HELD_PER_SOURCE`]; [`HELD`] on
    /// a board whose clients all arrive through one address, QEMU's user network).
    pub fn identify(&mut self, mac: [u8; 6], ip: [u8; 4], per_source: usize) {
        self.me = Some((mac, ip));
        self.per_source = core::num::NonZeroUsize::new(per_source.clamp(1, H.max(1)));
    }

    /// SYN frames held now.
    pub fn held(&self) -> usize {
        self.held.len()
    }

    /// Listening tasks not yet promised to a SYN.
    fn free(&self) -> usize {
        self.accepting.saturating_sub(self.in_flight.len())
    }

    fn expire(&mut self, now_ms: u64) {
        self.in_flight.retain(|&(_, at)| now_ms.saturating_sub(at) < HANDSHAKE_MS);
        while self.held.front().is_some_and(|h| now_ms.saturating_sub(h.at_ms) >= HOLD_MS) {
            self.held.pop_front();
        }
    }

    /// A connection task listens on `port`.
    pub fn listening(&mut self, port: u16) {
        self.port = port;
        self.accepting += 1;
    }

    /// A connection task's accept ended: with a connection from `peer`, or without (an
    /// error, `None`).
    pub fn accepted(&mut self, peer: Option<Peer>) {
        self.accepting = self.accepting.saturating_sub(1);
        if let Some(i) = peer.and_then(|peer| self.in_flight.iter().position(|&(p, _)| p == peer)) {
            self.in_flight.swap_remove(i);
        }
    }

    /// A frame from the wire at `now_ms`: to the stack, or held.
    pub fn arrive(&mut self, frame: &[u8], now_ms: u64) -> Verdict {
        if self.port == 0 {
            return Verdict::Pass;
        }
        let Some((peer, flags)) = segment_to(frame, self.port) else { return Verdict::Pass };
        self.expire(now_ms);
        let in_flight = self.in_flight.iter().position(|&(p, _)| p == peer);
        if flags & RST != 0 {
            // The client reset its handshake: smoltcp puts that socket back in LISTEN.
            if let Some(i) = in_flight {
                self.in_flight.swap_remove(i);
            }
            return Verdict::Pass;
        }
        if flags & (SYN | ACK | FIN) != SYN {
            return Verdict::Pass;
        }
        if self.me.is_some_and(|(mac, ip)| !for_me(frame, &mac, &ip)) {
            // Junk (another address, a damaged or forged frame): dropped here, so it never
            // takes a listening task's place (smoltcp would drop it, after that).
            return Verdict::Hold;
        }
        if in_flight.is_some() {
            // Sent again during its handshake: dropped (see the module's notes).
            return Verdict::Hold;
        }
        if self.held.is_empty() && self.free() > 0 {
            // `free() > 0` means fewer entries than listening tasks, at most SOCKETS.
            let _ = self.in_flight.push((peer, now_ms));
            return Verdict::Pass;
        }
        if let Some(held) = self.held.iter_mut().find(|h| h.peer == peer) {
            // The same client port again: a retransmission (the same frame), or a new
            // connection from a port the client reused (QEMU's user network does, in a flood)
            // with a new initial sequence number. The newest is the one its client waits for: it
            // takes the held one's place (a SYN-ACK to the old one is answered with a RST, and
            // the new connection would wait for its retransmission, seconds later).
            if frame.len() <= MAX_SYN_FRAME {
                held.frame[..frame.len()].copy_from_slice(frame);
                held.len = frame.len();
            }
            return Verdict::Hold;
        }
        if frame.len() > MAX_SYN_FRAME {
            // Too long to hold: the stack takes it now, or refuses it.
            if self.free() > 0 {
                let _ = self.in_flight.push((peer, now_ms));
            }
            return Verdict::Pass;
        }
        if self.held.iter().filter(|h| h.peer.ip == peer.ip).count()
            >= self.per_source.map_or(H, core::num::NonZeroUsize::get)
        {
            // One source's SYNs never fill the backlog: its newest replaces its oldest.
            if let Some(i) = self.held.iter().position(|h| h.peer.ip == peer.ip) {
                self.remove_held(i);
            }
        } else if self.held.is_full() {
            self.held.pop_front();
        }
        let mut held = HeldSyn { peer, at_ms: now_ms, len: frame.len(), frame: [0; MAX_SYN_FRAME] };
        held.frame[..frame.len()].copy_from_slice(frame);
        let _ = self.held.push_back(held);
        Verdict::Hold
    }

    /// Removes the held SYN at `index` (order kept).
    fn remove_held(&mut self, index: usize) {
        for _ in 0..index {
            if let Some(h) = self.held.pop_front() {
                let _ = self.held.push_back(h);
            }
        }
        self.held.pop_front();
        for _ in index..self.held.len() {
            if let Some(h) = self.held.pop_front() {
                let _ = self.held.push_back(h);
            }
        }
    }

    /// When the backlog changes by itself next (a held SYN or a handshake lapses), while SYNs
    /// wait: the runner must look again then.
    pub fn next_change(&self) -> Option<u64> {
        let held = self.held.front()?.at_ms + HOLD_MS;
        Some(self.in_flight.iter().map(|&(_, at)| at + HANDSHAKE_MS).fold(held, u64::min))
    }

    /// Whether a SYN is held and a task listens for it now.
    pub fn ready(&mut self, now_ms: u64) -> bool {
        if self.held.is_empty() {
            return false;
        }
        self.expire(now_ms);
        !self.held.is_empty() && self.free() > 0
    }

    /// The oldest held SYN, copied into `out`, if a task listens for it now: its length.
    pub fn release(&mut self, now_ms: u64, out: &mut [u8; MAX_SYN_FRAME]) -> Option<usize> {
        if !self.ready(now_ms) {
            return None;
        }
        let held = self.held.pop_front()?;
        let _ = self.in_flight.push((held.peer, now_ms));
        out[..held.len].copy_from_slice(&held.frame[..held.len]);
        Some(held.len)
    }
}

/// The backlog shared by the network runner (through [`Backlogged`]) and the connection tasks.
pub struct SynGate<const H: usize, const S: usize> {
    state: Mutex<CriticalSectionRawMutex, RefCell<(Backlog<H, S>, Option<Waker>)>>,
}

impl<const H: usize, const S: usize> Default for SynGate<H, S> {
    fn default() -> Self {
        Self::new()
    }
}

/// The Modbus port's gate.
pub type ModbusGate = SynGate<HELD, SOCKETS>;

/// The Modbus port's backlog on the boards that run embassy-net.
pub static MODBUS_BACKLOG: ModbusGate = SynGate::new();

/// SYNs for the web console's port held at most: a browser opens up to 6 connections to a
/// host at once (a page's files), and the console serves
/// [`WEB_CONNECTIONS`](remodaq_shared::sockets::WEB_CONNECTIONS) at a time; the rest wait here instead of
/// being reset.
#[cfg(feature = "web")]
pub const WEB_HELD: usize = 8;

/// The web console port's gate.
#[cfg(feature = "web")]
pub type WebGate = SynGate<WEB_HELD, { remodaq_shared::sockets::WEB_CONNECTIONS }>;

/// The web console port's backlog on the boards that run embassy-net.
#[cfg(feature = "web")]
pub static WEB_BACKLOG: WebGate = SynGate::new();

/// Every port's gate, in the order they see a frame.
pub static GATES: &[&dyn Gate] = &[
    &MODBUS_BACKLOG,
    #[cfg(feature = "web")]
    &WEB_BACKLOG,
];

/// The module's MAC and IPv4 address to every gate (the board, when its network starts; see
/// [`Backlog::identify`]): `per_source` for the Modbus port; the web port's SYNs come from
/// browsers, which open several connections at once, so one source may fill its backlog.
pub fn identify(mac: [u8; 6], ip: [u8; 4], per_source: usize) {
    MODBUS_BACKLOG.identify(mac, ip, per_source);
    #[cfg(feature = "web")]
    WEB_BACKLOG.identify(mac, ip, WEB_HELD);
}

/// A port's gate as the connection tasks and the driver wrapper see it.
pub trait Gate: Sync {
    /// The port its tasks listen on (0 before the first listens).
    fn port(&self) -> u16;
    /// A connection task listens on `port` (its socket already in LISTEN): a held SYN may go
    /// to the stack now, so the network runner is woken.
    fn listening(&self, port: u16);
    /// A connection task's accept ended, with a connection from `peer` or without.
    fn accepted(&self, peer: Option<Peer>);
    /// A frame from the wire at `now_ms`: to the stack, or held.
    fn arrive(&self, frame: &[u8], now_ms: u64) -> Verdict;
    /// Whether a held SYN can go to the stack now: `Ok`, or when to look again if one waits
    /// (the runner's waker is kept for when a task listens).
    fn ready(&self, now_ms: u64, cx: &Context<'_>) -> Result<(), Option<u64>>;
    /// The oldest held SYN, copied into `out`, if a task listens for it now: its length.
    fn release(&self, now_ms: u64, out: &mut [u8; MAX_SYN_FRAME]) -> Option<usize>;
}

impl<const H: usize, const S: usize> SynGate<H, S> {
    /// Empty.
    pub const fn new() -> Self {
        Self { state: Mutex::new(RefCell::new((Backlog::new(), None))) }
    }

    fn with<T>(&self, f: impl FnOnce(&mut Backlog<H, S>, &mut Option<Waker>) -> T) -> T {
        self.state.lock(|cell| {
            let mut state = cell.borrow_mut();
            let (backlog, waker) = &mut *state;
            f(backlog, waker)
        })
    }

    /// The module's MAC and IPv4 address, and the SYNs one source may have held
    /// ([`Backlog::identify`]).
    pub fn identify(&self, mac: [u8; 6], ip: [u8; 4], per_source: usize) {
        self.with(|backlog, _| backlog.identify(mac, ip, per_source));
    }
}

impl<const H: usize, const S: usize> Gate for SynGate<H, S> {
    fn port(&self) -> u16 {
        self.with(|backlog, _| backlog.port)
    }

    fn listening(&self, port: u16) {
        let waker = self.with(|backlog, waker| {
            backlog.listening(port);
            if backlog.held() > 0 {
                waker.take()
            } else {
                None
            }
        });
        if let Some(waker) = waker {
            waker.wake();
        }
    }

    fn accepted(&self, peer: Option<Peer>) {
        self.with(|backlog, _| backlog.accepted(peer));
    }

    fn arrive(&self, frame: &[u8], now_ms: u64) -> Verdict {
        self.with(|backlog, _| backlog.arrive(frame, now_ms))
    }

    fn ready(&self, now_ms: u64, cx: &Context<'_>) -> Result<(), Option<u64>> {
        self.with(|backlog, waker| {
            if backlog.ready(now_ms) {
                return Ok(());
            }
            if backlog.held() > 0 {
                *waker = Some(cx.waker().clone());
            }
            Err(backlog.next_change())
        })
    }

    fn release(&self, now_ms: u64, out: &mut [u8; MAX_SYN_FRAME]) -> Option<usize> {
        self.with(|backlog, _| backlog.release(now_ms, out))
    }
}

pub use driver::{Backlogged, Rx};

mod driver {
    use core::future::Future;
    use core::pin::Pin;
    use core::task::Context;

    use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState, RxToken};

    use super::{destination_port, Gate, Verdict, MAX_SYN_FRAME};

    use embassy_time::{Instant, Timer};

    fn now_ms() -> u64 {
        Instant::now().as_millis()
    }

    /// A board's Ethernet driver behind the ports' backlogs ([`GATES`](super::GATES)): every
    /// received frame is seen by the gates first; a held SYN reaches the stack later, from
    /// its gate's copy.
    pub struct Backlogged<D> {
        inner: D,
        gates: &'static [&'static dyn Gate],
        released: [u8; MAX_SYN_FRAME],
    }

    impl<D: Driver> Backlogged<D> {
        /// `inner` behind `gates`.
        pub fn new(inner: D, gates: &'static [&'static dyn Gate]) -> Self {
            Self { inner, gates, released: [0; MAX_SYN_FRAME] }
        }
    }

    /// What the gates make of a frame: the first gate of its destination port decides (one
    /// gate for a port, even were two services set to the same one); other frames pass.
    fn arrive(gates: &[&dyn Gate], frame: &[u8], now_ms: u64) -> Verdict {
        let Some(port) = destination_port(frame) else { return Verdict::Pass };
        gates.iter().find(|gate| gate.port() == port).map_or(Verdict::Pass, |gate| gate.arrive(frame, now_ms))
    }

    /// A received frame: the driver's own (the gate looks at it as the stack takes it), or a
    /// held SYN the gate released.
    pub enum Rx<'a, T> {
        /// From the driver.
        Wire(T, &'static [&'static dyn Gate]),
        /// A released SYN.
        Released(&'a mut [u8]),
    }

    impl<T: RxToken> RxToken for Rx<'_, T> {
        fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
            match self {
                Rx::Wire(token, gates) => token.consume(|frame| match arrive(gates, frame, now_ms()) {
                    Verdict::Pass => f(frame),
                    // The stack drops an empty frame (too short for Ethernet) without a word.
                    Verdict::Hold => f(&mut []),
                }),
                Rx::Released(frame) => f(frame),
            }
        }
    }

    impl<D: Driver> Driver for Backlogged<D> {
        type RxToken<'a>
            = Rx<'a, D::RxToken<'a>>
        where
            Self: 'a;
        type TxToken<'a>
            = D::TxToken<'a>
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
                        let tx = self.inner.transmit(cx)?;
                        let len = gate.release(now, &mut self.released)?;
                        return Some((Rx::Released(&mut self.released[..len]), tx));
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
            Some((Rx::Wire(rx, self.gates), tx))
        }

        fn transmit(&mut self, cx: &mut Context) -> Option<Self::TxToken<'_>> {
            self.inner.transmit(cx)
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec as StdVec;

    const PORT: u16 = 8000;

    /// An Ethernet II frame with an IPv4 header (no options) and a TCP header with `options`
    /// bytes of options, from 10.0.2.2:`from` to 10.0.2.15:`to`, with TCP `flags`. Laid out by
    /// hand from RFC 791 §3.1 and RFC 9293 §3.1 (checksums left 0: the backlog reads none).
    fn segment(from: u16, to: u16, flags: u8, options: usize) -> StdVec<u8> {
        let tcp_len = 20 + options;
        let total = 20 + tcp_len;
        let mut f = StdVec::new();
        f.extend_from_slice(&[0x02, 0, 0, 0, 0, 0x15, 0x52, 0x55, 10, 0, 2, 2, 0x08, 0x00]);
        f.extend_from_slice(&[0x45, 0, (total >> 8) as u8, total as u8, 0, 1, 0x40, 0, 64, 6, 0, 0]);
        f.extend_from_slice(&[10, 0, 2, 2, 10, 0, 2, 15]);
        f.extend_from_slice(&from.to_be_bytes());
        f.extend_from_slice(&to.to_be_bytes());
        f.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 0, ((tcp_len / 4) << 4) as u8, flags, 0xFA, 0xF0, 0, 0, 0, 0]);
        f.resize(14 + total, 1); // option bytes: NOP (1)
        f
    }

    const SYN: u8 = 0x02;

    fn syn(from: u16) -> StdVec<u8> {
        segment(from, PORT, SYN, 20)
    }

    fn peer(port: u16) -> Peer {
        Peer { ip: [10, 0, 2, 2], port }
    }

    #[test]
    fn recognises_only_a_connection_request_to_the_port() {
        assert_eq!(syn_to(&syn(40000), PORT), Some(peer(40000)));
        assert_eq!(syn_to(&segment(40000, PORT, SYN, 0), PORT), Some(peer(40000)));
        // SYN-ACK, ACK, RST+SYN, SYN+FIN, FIN, another port: not a request to the Modbus port.
        for flags in [0x12, 0x10, 0x06, 0x03, 0x01, 0x18] {
            assert_eq!(syn_to(&segment(40000, PORT, flags, 0), PORT), None, "flags {flags:02x}");
        }
        assert_eq!(syn_to(&segment(40000, 8301, SYN, 0), PORT), None);
        // UDP (protocol 17), IPv6 EtherType, IPv4 with version 6, a later fragment.
        let mut udp = syn(40000);
        udp[14 + 9] = 17;
        assert_eq!(syn_to(&udp, PORT), None);
        let mut v6 = syn(40000);
        v6[12..14].copy_from_slice(&[0x86, 0xDD]);
        assert_eq!(syn_to(&v6, PORT), None);
        let mut bad_version = syn(40000);
        bad_version[14] = 0x65;
        assert_eq!(syn_to(&bad_version, PORT), None);
        let mut fragment = syn(40000);
        fragment[14 + 6..14 + 8].copy_from_slice(&[0x20, 0x00]); // more fragments
        assert_eq!(syn_to(&fragment, PORT), None);
    }

    #[test]
    fn an_ip_header_with_options_moves_the_tcp_header() {
        // IHL 6: four option bytes (NOP x4) before TCP.
        let plain = segment(40001, PORT, SYN, 0);
        let mut f = plain[..34].to_vec();
        f[14] = 0x46;
        f.extend_from_slice(&[1, 1, 1, 1]);
        f.extend_from_slice(&plain[34..]);
        assert_eq!(syn_to(&f, PORT), Some(peer(40001)));
    }

    /// A SYN from 10.0.2.2:40000 to 10.0.2.15:8000 (MAC 02:00:00:00:00:15) with both checksums
    /// right, computed independently (Python, RFC 1071).
    const GOOD_SYN: &str = "02 00 00 00 00 15 52 55 0a 00 02 02 08 00 45 00 00 28 00 01 40 00 40 06 22 bf \
        0a 00 02 02 0a 00 02 0f 9c 40 1f 40 00 00 00 01 00 00 00 00 50 02 fa f0 e1 5f 00 00";
    const MY_MAC: [u8; 6] = [0x02, 0, 0, 0, 0, 0x15];
    const MY_IP: [u8; 4] = [10, 0, 2, 15];

    fn good_syn() -> StdVec<u8> {
        GOOD_SYN.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
    }

    #[test]
    fn only_intact_syns_for_this_module_take_a_listener() {
        let good = good_syn();
        assert!(for_me(&good, &MY_MAC, &MY_IP));
        let mut good_with_fcs = good.clone();
        good_with_fcs.extend_from_slice(&[0xDE, 0xAD, 0xBE, 0xEF]);
        assert!(for_me(&good_with_fcs, &MY_MAC, &MY_IP), "the frame check sequence after the packet");
        let junk = |at: usize| {
            let mut f = good.clone();
            f[at] ^= 0x01;
            f
        };
        // Another MAC, another destination IP, a damaged IP header, a damaged TCP segment.
        for (what, frame) in [("mac", junk(5)), ("ip", junk(33)), ("ip header", junk(22)), ("tcp", junk(49))] {
            assert!(!for_me(&frame, &MY_MAC, &MY_IP), "{what}");
            let mut b = ModbusBacklog::new();
            b.identify(MY_MAC, MY_IP, HELD_PER_SOURCE);
            b.listening(PORT);
            assert_eq!(b.arrive(&frame, 0), Verdict::Hold, "{what}: dropped");
            assert_eq!((b.held(), b.free()), (0, 1), "{what}: the listener is still free");
            assert_eq!(b.arrive(&good, 0), Verdict::Pass, "{what}: then a real client gets it");
        }
    }

    #[test]
    fn one_source_holds_at_most_four_syns() {
        let mut b = ModbusBacklog::new();
        b.identify([0x02, 0, 0, 0, 0, 0x15], [10, 0, 2, 15], HELD_PER_SOURCE);
        b.me = None; // the hand-built frames carry no checksums
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass, "takes the one listener");
        for port in 2..20 {
            assert_eq!(b.arrive(&syn(port), 0), Verdict::Hold);
        }
        assert_eq!(b.held(), HELD_PER_SOURCE);
        // The newest ones, in order.
        b.accepted(Some(peer(1)));
        b.listening(PORT);
        let mut out = [0u8; MAX_SYN_FRAME];
        let n = b.release(0, &mut out).unwrap();
        assert_eq!(syn_to(&out[..n], PORT), Some(peer(16)));
    }

    #[test]
    fn a_truncated_frame_is_never_a_request_and_never_panics() {
        let f = syn(40000);
        for len in 0..f.len() {
            // The TCP flags are at byte 14 + 20 + 13 = 47: anything shorter is not a SYN.
            let expected = if len > 47 { Some(peer(40000)) } else { None };
            assert_eq!(syn_to(&f[..len], PORT), expected, "length {len}");
            let mut b = ModbusBacklog::new();
            b.listening(PORT);
            let _ = b.arrive(&f[..len], 0);
        }
    }

    #[test]
    fn a_syn_passes_while_a_task_listens_and_is_held_after() {
        let mut b = ModbusBacklog::new();
        // No task has listened yet: the port is unknown, everything passes.
        assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
        b.listening(PORT);
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(2), 0), Verdict::Pass);
        assert_eq!(b.arrive(&syn(3), 0), Verdict::Pass);
        assert_eq!(b.arrive(&syn(4), 0), Verdict::Hold);
        assert_eq!(b.arrive(&syn(5), 0), Verdict::Hold);
        // Other traffic is never held.
        assert_eq!(b.arrive(&segment(2, PORT, 0x10, 0), 0), Verdict::Pass);
        assert_eq!(b.held(), 2);
        // A SYN sent again during its handshake is dropped (its socket sends the SYN-ACK again).
        assert_eq!(b.arrive(&syn(2), 1), Verdict::Hold);
        assert_eq!(b.held(), 2);
        // A SYN already held, sent again: still one held.
        assert_eq!(b.arrive(&syn(4), 1), Verdict::Hold);
        assert_eq!(b.held(), 2);
    }

    #[test]
    fn a_new_connection_from_a_held_port_replaces_the_held_syn() {
        // The client reused port 4 for a new connection (a new initial sequence number) while
        // its first SYN was held: the newer SYN is the one released, in the first one's place.
        let mut b = ModbusBacklog::new();
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(2), 0), Verdict::Pass);
        assert_eq!(b.arrive(&syn(4), 0), Verdict::Hold);
        assert_eq!(b.arrive(&syn(5), 0), Verdict::Hold);
        let mut again = syn(4);
        again[38..42].copy_from_slice(&[0, 0x40, 0x77, 0x01]); // another sequence number
        assert_eq!(b.arrive(&again, 1), Verdict::Hold);
        assert_eq!(b.held(), 2);
        b.accepted(Some(Peer { ip: [10, 0, 2, 2], port: 2 }));
        b.listening(PORT);
        let mut out = [0u8; MAX_SYN_FRAME];
        let n = b.release(2, &mut out).expect("port 4 first");
        assert_eq!(&out[..n], &again[..], "the newer SYN");
    }

    #[test]
    fn held_syns_go_in_arrival_order_as_tasks_listen_again() {
        let mut b = ModbusBacklog::new();
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(10), 0), Verdict::Pass);
        for port in 11..15 {
            assert_eq!(b.arrive(&syn(port), 0), Verdict::Hold);
        }
        let mut out = [0u8; MAX_SYN_FRAME];
        assert_eq!(b.release(1, &mut out), None, "the one task is in a handshake");
        // Its handshake completes; it accepts, then listens again (an evicted task as well).
        b.accepted(Some(peer(10)));
        assert_eq!(b.release(1, &mut out), None, "no task listens");
        b.listening(PORT);
        b.listening(PORT);
        for expected in [11, 12] {
            let len = b.release(2, &mut out).expect("a task listens");
            assert_eq!(&out[..len], &syn(expected)[..]);
        }
        assert_eq!(b.release(2, &mut out), None, "both tasks are promised");
        // A SYN arriving now queues behind the held ones even when a task listens.
        b.accepted(Some(peer(11)));
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(15), 3), Verdict::Hold);
        let len = b.release(3, &mut out).expect("a task listens");
        assert_eq!(&out[..len], &syn(13)[..]);
    }

    #[test]
    fn a_full_backlog_drops_its_oldest_syn_for_the_newcomer() {
        let mut b = ModbusBacklog::new();
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(100), 0), Verdict::Pass);
        for i in 0..HELD as u16 + 1 {
            assert_eq!(b.arrive(&syn(200 + i), 0), Verdict::Hold);
        }
        assert_eq!(b.held(), HELD);
        b.accepted(Some(peer(100)));
        b.listening(PORT);
        let mut out = [0u8; MAX_SYN_FRAME];
        let len = b.release(0, &mut out).expect("a task listens");
        assert_eq!(&out[..len], &syn(201)[..], "the oldest (200) was dropped");
        // The newcomer, last in, is still there.
        let mut last = None;
        for _ in 0..HELD {
            b.accepted(None);
            b.listening(PORT);
            b.in_flight.clear();
            if let Some(len) = b.release(0, &mut out) {
                last = Some(out[..len].to_vec());
            }
        }
        assert_eq!(last, Some(syn(200 + HELD as u16)));
    }

    #[test]
    fn old_syns_and_stalled_handshakes_expire() {
        let mut b = ModbusBacklog::new();
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
        assert_eq!(b.arrive(&syn(2), 0), Verdict::Hold);
        assert_eq!(b.next_change(), Some(HOLD_MS), "SYN 2 lapses first");
        assert_eq!(b.arrive(&syn(3), HOLD_MS - 1), Verdict::Hold);
        let mut out = [0u8; MAX_SYN_FRAME];
        assert_eq!(b.release(HANDSHAKE_MS - 1, &mut out), None, "the one task is in a handshake");
        assert_eq!(b.held(), 0, "both SYNs were held for HOLD_MS and dropped");
        assert_eq!(b.next_change(), None);
        // The first handshake never completed: after HANDSHAKE_MS (longer than the task waits
        // for it) the task counts as listening again.
        assert_eq!(b.arrive(&syn(4), HANDSHAKE_MS - 1), Verdict::Hold);
        assert_eq!(b.next_change(), Some(HANDSHAKE_MS), "the handshake lapses before SYN 4");
        assert_eq!(b.release(HANDSHAKE_MS, &mut out), Some(syn(4).len()));
        assert_eq!(&out[..syn(4).len()], &syn(4)[..]);
    }

    #[test]
    fn a_client_that_resets_its_handshake_frees_the_task() {
        let mut b = ModbusBacklog::new();
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
        assert_eq!(b.arrive(&syn(2), 0), Verdict::Hold);
        let mut out = [0u8; MAX_SYN_FRAME];
        assert_eq!(b.release(1, &mut out), None);
        // A RST from another client changes nothing; one from client 1 frees its task (smoltcp
        // puts the socket in SYN-RECEIVED back in LISTEN).
        assert_eq!(b.arrive(&segment(9, PORT, 0x04, 0), 1), Verdict::Pass);
        assert_eq!(b.release(1, &mut out), None);
        assert_eq!(b.arrive(&segment(1, PORT, 0x14, 0), 2), Verdict::Pass);
        assert_eq!(b.release(2, &mut out), Some(syn(2).len()));
    }

    #[test]
    fn a_syn_too_long_to_hold_goes_to_the_stack() {
        let mut b = ModbusBacklog::new();
        b.listening(PORT);
        assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
        // The longest TCP header (60 bytes) with a frame check sequence after it is held; a
        // frame longer than that (here TCP options beyond the limit, as IP options would make
        // it) goes to the stack.
        let mut longest = segment(2, PORT, SYN, 40);
        longest.extend_from_slice(&[0xDE, 0xAD, 0xBE, 0xEF]);
        assert_eq!(longest.len(), MAX_SYN_FRAME);
        assert_eq!(b.arrive(&longest, 0), Verdict::Hold);
        assert_eq!(b.arrive(&segment(3, PORT, SYN, 48), 0), Verdict::Pass);
        assert_eq!(b.held(), 1);
    }

    /// A fake driver: frames to receive, and the frames the stack sent.
    struct Wire {
        inbox: std::collections::VecDeque<StdVec<u8>>,
    }

    struct FakeRx(StdVec<u8>);
    struct FakeTx;

    impl RxToken for FakeRx {
        fn consume<R, F: FnOnce(&mut [u8]) -> R>(mut self, f: F) -> R {
            f(&mut self.0)
        }
    }

    impl embassy_net_driver::TxToken for FakeTx {
        fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
            f(&mut std::vec![0; len])
        }
    }

    use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState, RxToken};

    impl Driver for Wire {
        type RxToken<'a> = FakeRx;
        type TxToken<'a> = FakeTx;
        fn receive(&mut self, _: &mut Context) -> Option<(FakeRx, FakeTx)> {
            self.inbox.pop_front().map(|f| (FakeRx(f), FakeTx))
        }
        fn transmit(&mut self, _: &mut Context) -> Option<FakeTx> {
            Some(FakeTx)
        }
        fn link_state(&mut self, _: &mut Context) -> LinkState {
            LinkState::Up
        }
        fn capabilities(&self) -> Capabilities {
            Capabilities::default()
        }
        fn hardware_address(&self) -> HardwareAddress {
            HardwareAddress::Ethernet([2, 0, 0, 0, 0, 0x15])
        }
    }

    /// What the stack would see: the frames it gets from the driver, in order.
    fn drain(driver: &mut Backlogged<Wire>, cx: &mut Context) -> StdVec<StdVec<u8>> {
        let mut seen = StdVec::new();
        while let Some((rx, _tx)) = driver.receive(cx) {
            rx.consume(|frame| seen.push(frame.to_vec()));
        }
        seen
    }

    #[test]
    fn the_driver_wrapper_holds_and_releases_syns_and_wakes_the_runner() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::sync::Arc;
        use std::task::Wake;
        struct Count(AtomicUsize);
        impl Wake for Count {
            fn wake(self: Arc<Self>) {
                self.0.fetch_add(1, Ordering::Relaxed);
            }
        }
        static GATE: ModbusGate = SynGate::new();
        static GATES: &[&dyn Gate] = &[&GATE];
        let count = Arc::new(Count(AtomicUsize::new(0)));
        let waker = Waker::from(count.clone());
        let mut cx = Context::from_waker(&waker);
        let ack = segment(9, PORT, 0x10, 0);
        let mut driver =
            Backlogged::new(Wire { inbox: [syn(1), syn(2), ack.clone(), syn(3)].into_iter().collect() }, GATES);
        GATE.listening(PORT);
        // The stack sees the first SYN and the ACK; the other SYNs reach it as empty frames.
        assert_eq!(drain(&mut driver, &mut cx), [syn(1), StdVec::new(), ack, StdVec::new()]);
        assert_eq!(count.0.load(Ordering::Relaxed), 0);
        // A task accepts the first and another listens: the runner is woken, gets SYN 2 only.
        GATE.accepted(Some(peer(1)));
        GATE.listening(PORT);
        assert_eq!(count.0.load(Ordering::Relaxed), 1);
        assert_eq!(drain(&mut driver, &mut cx), [syn(2)]);
        GATE.accepted(Some(peer(2)));
        GATE.listening(PORT);
        assert_eq!(count.0.load(Ordering::Relaxed), 2);
        assert_eq!(drain(&mut driver, &mut cx), [syn(3)]);
    }

    #[test]
    fn each_port_has_its_own_gate() {
        // A second port (the web console's, 80) with 2 SYNs held at most and one task.
        static MODBUS: ModbusGate = SynGate::new();
        static WEB: SynGate<2, 1> = SynGate::new();
        static BOTH: &[&dyn Gate] = &[&MODBUS, &WEB];
        let waker = Waker::noop();
        let mut cx = Context::from_waker(waker);
        let web_syn = |from| segment(from, 80, SYN, 20);
        let inbox = [syn(1), web_syn(2), web_syn(3), web_syn(4), web_syn(5), syn(6)];
        let mut driver = Backlogged::new(Wire { inbox: inbox.into_iter().collect() }, BOTH);
        MODBUS.listening(PORT);
        MODBUS.listening(PORT);
        WEB.listening(80);
        // Modbus's two SYNs and the web's first reach the stack; web SYNs 3-5 wait (the
        // backlog keeps the newest 2: 4 and 5).
        assert_eq!(
            drain(&mut driver, &mut cx),
            [syn(1), web_syn(2), StdVec::new(), StdVec::new(), StdVec::new(), syn(6)]
        );
        // Modbus tasks listening again release nothing of the web's.
        MODBUS.accepted(Some(peer(1)));
        MODBUS.listening(PORT);
        assert_eq!(drain(&mut driver, &mut cx), StdVec::<StdVec<u8>>::new());
        // The web task accepts 2 and listens again: 4 comes, then 5 after the next.
        WEB.accepted(Some(peer(2)));
        WEB.listening(80);
        assert_eq!(drain(&mut driver, &mut cx), [web_syn(4)]);
        WEB.accepted(Some(peer(4)));
        WEB.listening(80);
        assert_eq!(drain(&mut driver, &mut cx), [web_syn(5)]);
    }

    #[test]
    fn two_gates_on_one_port_the_first_decides() {
        // Two services set to the same port: one gate decides for it; the other never holds a
        // SYN or counts one as promised.
        static FIRST: SynGate<2, 1> = SynGate::new();
        static SECOND: SynGate<2, 1> = SynGate::new();
        static SAME: &[&dyn Gate] = &[&FIRST, &SECOND];
        let waker = Waker::noop();
        let mut cx = Context::from_waker(waker);
        let mut driver = Backlogged::new(Wire { inbox: [syn(1), syn(2)].into_iter().collect() }, SAME);
        FIRST.listening(PORT);
        SECOND.listening(PORT);
        assert_eq!(drain(&mut driver, &mut cx), [syn(1), StdVec::new()]);
        assert_eq!(FIRST.with(|b, _| (b.held(), b.in_flight.len())), (1, 1));
        assert_eq!(SECOND.with(|b, _| (b.held(), b.in_flight.len())), (0, 0));
    }
}
