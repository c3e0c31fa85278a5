//! The backlog's queue: its bounds, the SYNs held and the handshakes under way for one port
//! ([`Backlog`]), plain logic over a millisecond clock.

use heapless::{Deque, Vec};

use remodaq_shared::sockets::MODBUS_SOCKETS as SOCKETS;

use super::frame::{for_me, segment_to, Peer, ACK, FIN, RST, SYN};

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

/// SYNs one source address may have held at once: its newest replaces its oldest.
pub const HELD_PER_SOURCE: usize = 4;

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
    pub(super) port: u16,
    /// Connection tasks listening on `port` (or in a handshake they have not finished).
    accepting: usize,
    /// SYNs let through whose handshakes are under way, and when.
    pub(super) in_flight: Vec<(Peer, u64), S>,
    held: Deque<HeldSyn, H>,
    /// The module's MAC and IPv4 address, once the board said: SYNs for anything else, or
    /// damaged, are dropped before they can take a listening task's place.
    pub(super) me: Option<([u8; 6], [u8; 4])>,
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
    pub(super) fn free(&self) -> usize {
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
