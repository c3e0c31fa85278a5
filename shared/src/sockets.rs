//! The module's socket plan: how many connections each network service holds at once. The
//! services take their counts from here, and so do the boards' TCP/IP stacks and the SYN backlog
//! (`remodaq-net`), which are sized for every service at once without importing any of them.

/// Modbus/TCP clients served at once (spec §1.1).
pub const MODBUS_CONNECTIONS: usize = 8;
/// Modbus/TCP connections one source address may hold at once.
pub const MODBUS_PER_SOURCE: usize = 4;
/// Modbus/TCP connection tasks a board runs: two more than [`MODBUS_CONNECTIONS`], so that while
/// one accepts a newcomer (and the connection idle the longest is being closed to make room)
/// another still listens: a TCP stack without a listen backlog (smoltcp) refuses a SYN no
/// socket listens for.
pub const MODBUS_SOCKETS: usize = MODBUS_CONNECTIONS + 2;
/// Sockets the discovery service replies through on an embassy-net board, beside the one it
/// receives on: a reply waiting for an ARP answer that never comes holds one of them, never
/// the requests behind it (security review finding 5, `remodaq-discovery`'s `embassy`).
pub const DISCOVERY_SENDERS: usize = 3;
/// The discovery service's sockets on an embassy-net board.
pub const DISCOVERY_SOCKETS: usize = 1 + DISCOVERY_SENDERS;
/// HTTP connections of the web console served at once (issue #25: at most 2, each in a task of
/// its own, never a Modbus slot).
pub const WEB_CONNECTIONS: usize = 2;
