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

mod driver;
pub(crate) mod frame;
mod gate;
mod queue;
#[cfg(test)]
mod tests;

pub use driver::{Backlogged, Rx};
pub use frame::{destination_port, for_me, syn_to, tcp_segment, Peer, Segment};
pub use gate::{identify, Gate, ModbusGate, SynGate, GATES, MODBUS_BACKLOG};
#[cfg(feature = "web")]
pub use gate::{WebGate, WEB_BACKLOG, WEB_HELD};
pub use queue::{
    Backlog, ModbusBacklog, Verdict, HANDSHAKE_MS, HANDSHAKE_TIMEOUT_MS, HELD, HELD_PER_SOURCE, HOLD_MS, MAX_SYN_FRAME,
};
