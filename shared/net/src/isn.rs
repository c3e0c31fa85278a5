//! Keyed initial sequence numbers (RFC 6528) for smoltcp's TCP: security review finding 6.
//!
//! smoltcp draws each connection's initial sequence number (ISN) from its generator, an sPCG32
//! seeded once by the board and never stirred: every output shows 32 of its 64 bits of state,
//! so the ISNs of three connections an attacker opens itself give the state away after at most
//! 2^32 guesses, and with it every later ISN, those of other hosts' connections included
//! (docs/security.md, "What is not protected", "A source address is not an identity"). RFC 6528 §3 makes the ISN
//! `M + F(localip, localport, remoteip, remoteport, secretkey)`: here M is smoltcp's own ISN and
//! F is SipHash-1-3 under a key from the board's entropy, so the ISN of a connection of another
//! address or port is smoltcp's plus a number the attacker cannot compute.
//!
//! smoltcp is not changed. The driver wrapper every embassy-net board uses
//! ([`crate::backlog::Backlogged`]) adds F to the sequence number of each TCP segment the module
//! sends ([`outgoing`]) and takes it off the acknowledgment number and the SACK blocks of each
//! segment it receives ([`incoming`]), and corrects the TCP checksum for the change (RFC 1624
//! eqn. 3) where the stack computes it. The stack sees its own numbers, the wire carries the
//! keyed ones; nothing else of a segment changes.

use siphasher::sip::SipHasher13;

/// The key of [`offset`]: 16 bytes of the board's entropy, drawn at start.
#[derive(Clone, Copy)]
pub struct IsnKey([u8; 16]);

impl IsnKey {
    /// The key from the board's entropy.
    pub const fn new(key: [u8; 16]) -> Self {
        Self(key)
    }
}

/// An end of a TCP connection: IPv4 address and port.
type End = ([u8; 4], u16);

/// F of RFC 6528 §3: the keyed hash of the connection's two ends, the module's first.
pub fn offset(key: &IsnKey, local: End, remote: End) -> u32 {
    use core::hash::Hasher;
    let mut hasher = SipHasher13::new_with_key(&key.0);
    let mut ends = [0u8; 12];
    ends[..4].copy_from_slice(&local.0);
    ends[4..6].copy_from_slice(&local.1.to_be_bytes());
    ends[6..10].copy_from_slice(&remote.0);
    ends[10..].copy_from_slice(&remote.1.to_be_bytes());
    hasher.write(&ends);
    hasher.finish() as u32
}

/// TCP's ACK flag (RFC 9293 §3.1).
const ACK: u8 = 0x10;
/// The SACK option (RFC 2018 §3).
const SACK: u8 = 5;

/// Where the TCP header of an Ethernet II frame starts, and its length (data offset): the frame
/// must carry a whole IPv4 TCP segment, not a fragment.
fn tcp_header(frame: &[u8]) -> Option<(usize, usize)> {
    let at = crate::backlog::frame::tcp_at(frame)?;
    let length = usize::from(*frame.get(at + 12)? >> 4) * 4;
    (length >= 20 && frame.len() >= at + length).then_some((at, length))
}

fn word(frame: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([frame[at], frame[at + 1], frame[at + 2], frame[at + 3]])
}

/// Replaces the 32-bit word at `at` (inside the TCP header at `tcp`) by `new`, and the TCP
/// checksum with it when `checksum` (RFC 1624 eqn. 3: HC' = ~(~HC + ~m + m'), per 16-bit word).
fn rewrite(frame: &mut [u8], tcp: usize, at: usize, new: u32, checksum: bool) {
    let old = word(frame, at);
    frame[at..at + 4].copy_from_slice(&new.to_be_bytes());
    if checksum {
        let held = u16::from_be_bytes([frame[tcp + 16], frame[tcp + 17]]);
        let mut sum = u32::from(!held);
        for (m, m2) in [(old >> 16, new >> 16), (old & 0xFFFF, new & 0xFFFF)] {
            sum += u32::from(!(m as u16)) + m2;
        }
        while sum > 0xFFFF {
            sum = (sum & 0xFFFF) + (sum >> 16);
        }
        frame[tcp + 16..tcp + 18].copy_from_slice(&(!(sum as u16)).to_be_bytes());
    }
}

/// The module's end and the peer's of a segment, from its IPv4 and TCP headers.
fn ends(frame: &[u8], tcp: usize, sent: bool) -> (End, End) {
    let source = ([frame[26], frame[27], frame[28], frame[29]], u16::from_be_bytes([frame[tcp], frame[tcp + 1]]));
    let destination =
        ([frame[30], frame[31], frame[32], frame[33]], u16::from_be_bytes([frame[tcp + 2], frame[tcp + 3]]));
    if sent {
        (source, destination)
    } else {
        (destination, source)
    }
}

/// A segment the module sends: its sequence number plus F; the TCP checksum corrected when
/// `checksum` (the stack computed it: with checksum offload the hardware fills it in after).
/// Any other frame is left as it is.
pub fn outgoing(key: &IsnKey, frame: &mut [u8], checksum: bool) {
    let Some((tcp, _)) = tcp_header(frame) else { return };
    let (local, remote) = ends(frame, tcp, true);
    let sequence = word(frame, tcp + 4).wrapping_add(offset(key, local, remote));
    rewrite(frame, tcp, tcp + 4, sequence, checksum);
}

/// A segment the module receives: its acknowledgment number (when ACK is set) and the edges of
/// its SACK blocks, which count the module's bytes, less F; the TCP checksum corrected, so that
/// the stack's own check still holds. Any other frame is left as it is.
pub fn incoming(key: &IsnKey, frame: &mut [u8]) {
    let Some((tcp, length)) = tcp_header(frame) else { return };
    let (local, remote) = ends(frame, tcp, false);
    let f = offset(key, local, remote);
    if frame[tcp + 13] & ACK != 0 {
        let ack = word(frame, tcp + 8).wrapping_sub(f);
        rewrite(frame, tcp, tcp + 8, ack, true);
    }
    // The options (RFC 9293 §3.1): kind 0 ends them, kind 1 is one byte, others carry a length.
    let mut at = tcp + 20;
    let end = tcp + length;
    while at < end {
        match frame[at] {
            0 => break,
            1 => at += 1,
            kind => {
                let Some(&len) = frame.get(at + 1).filter(|&&len| len >= 2) else { break };
                let next = at + usize::from(len);
                if next > end {
                    break;
                }
                if kind == SACK {
                    let mut edge = at + 2;
                    while edge + 4 <= next {
                        let moved = word(frame, edge).wrapping_sub(f);
                        rewrite(frame, tcp, edge, moved, true);
                        edge += 4;
                    }
                }
                at = next;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::vec::Vec;

    use super::*;

    /// The RFC 1071 checksum of a TCP segment over its pseudo-header, computed from scratch.
    fn tcp_checksum_ok(frame: &[u8]) -> bool {
        let (tcp, _) = tcp_header(frame).unwrap();
        let total = usize::from(u16::from_be_bytes([frame[16], frame[17]]));
        let segment = &frame[tcp..14 + total];
        let mut bytes = Vec::new();
        bytes.extend_from_slice(&frame[26..34]);
        bytes.extend_from_slice(&[0, 6]);
        bytes.extend_from_slice(&(segment.len() as u16).to_be_bytes());
        bytes.extend_from_slice(segment);
        if bytes.len() % 2 == 1 {
            bytes.push(0);
        }
        let mut sum: u32 = bytes.chunks(2).map(|w| u32::from(u16::from_be_bytes([w[0], w[1]]))).sum();
        while sum > 0xFFFF {
            sum = (sum & 0xFFFF) + (sum >> 16);
        }
        sum == 0xFFFF
    }

    /// An Ethernet II frame with an IPv4 TCP segment from `from` to `to`: sequence and
    /// acknowledgment numbers, flags, options, 5 bytes of data, and a right TCP checksum.
    fn segment(from: End, to: End, seq: u32, ack: u32, flags: u8, options: &[u8]) -> Vec<u8> {
        let tcp_len = 20 + options.len();
        let mut f = std::vec![0u8; 14 + 20 + tcp_len + 5];
        f[12..14].copy_from_slice(&[0x08, 0x00]);
        f[14] = 0x45;
        f[16..18].copy_from_slice(&((20 + tcp_len + 5) as u16).to_be_bytes());
        f[23] = 6;
        f[26..30].copy_from_slice(&from.0);
        f[30..34].copy_from_slice(&to.0);
        let t = 34;
        f[t..t + 2].copy_from_slice(&from.1.to_be_bytes());
        f[t + 2..t + 4].copy_from_slice(&to.1.to_be_bytes());
        f[t + 4..t + 8].copy_from_slice(&seq.to_be_bytes());
        f[t + 8..t + 12].copy_from_slice(&ack.to_be_bytes());
        f[t + 12] = ((tcp_len / 4) as u8) << 4;
        f[t + 13] = flags;
        f[t + 20..t + tcp_len].copy_from_slice(options);
        f[t + tcp_len..].copy_from_slice(b"hello");
        // The checksum that makes the sum come out right.
        let mut bytes = Vec::new();
        bytes.extend_from_slice(&f[26..34]);
        bytes.extend_from_slice(&[0, 6]);
        bytes.extend_from_slice(&((tcp_len + 5) as u16).to_be_bytes());
        bytes.extend_from_slice(&f[t..]);
        bytes.push(0);
        let mut sum: u32 = bytes.chunks(2).map(|w| u32::from(u16::from_be_bytes([w[0], w[1]]))).sum();
        while sum > 0xFFFF {
            sum = (sum & 0xFFFF) + (sum >> 16);
        }
        f[t + 16..t + 18].copy_from_slice(&(!(sum as u16)).to_be_bytes());
        assert!(tcp_checksum_ok(&f));
        f
    }

    const MODULE: End = ([192, 168, 0, 1], 8000);
    const PC: End = ([192, 168, 0, 10], 50_000);
    const KEY: IsnKey = IsnKey::new(*b"sixteen byte key");

    #[test]
    fn the_wire_carries_the_stacks_numbers_plus_f_and_the_stack_gets_its_own_back() {
        let f = offset(&KEY, MODULE, PC);
        // The module's SYN-ACK: its ISN 1000 leaves as 1000 + F, the checksum still right.
        let mut sent = segment(MODULE, PC, 1000, 7, 0x12, &[]);
        outgoing(&KEY, &mut sent, true);
        assert_eq!(word(&sent, 38), 1000u32.wrapping_add(f));
        assert_eq!(word(&sent, 42), 7, "the peer's numbers are not the module's to change");
        assert!(tcp_checksum_ok(&sent));
        // The PC acknowledges 1001 + F and SACKs two blocks of the module's bytes: the stack sees
        // 1001 and blocks in its own numbers, the checksum right.
        let sack = |a: u32, b: u32, c: u32, d: u32| {
            let mut o = std::vec![1, 1, SACK, 18];
            for x in [a, b, c, d] {
                o.extend_from_slice(&x.wrapping_add(f).to_be_bytes());
            }
            o.extend_from_slice(&[0, 0]);
            o
        };
        let mut received = segment(PC, MODULE, 8, 1001u32.wrapping_add(f), ACK, &sack(2000, 2100, 3000, 3100));
        incoming(&KEY, &mut received);
        assert_eq!((word(&received, 38), word(&received, 42)), (8, 1001));
        let edges: Vec<u32> = (0..4).map(|i| word(&received, 34 + 20 + 4 + 4 * i)).collect();
        assert_eq!(edges, [2000, 2100, 3000, 3100]);
        assert!(tcp_checksum_ok(&received));
        // Without ACK (a SYN) the acknowledgment field is not a number of the module's.
        let mut syn = segment(PC, MODULE, 8, 12345, 0x02, &[]);
        incoming(&KEY, &mut syn);
        assert_eq!(word(&syn, 42), 12345);
        // With checksum offload the stack leaves the field for the hardware: untouched here.
        let mut offloaded = segment(MODULE, PC, 1000, 7, 0x12, &[]);
        let field = [offloaded[50], offloaded[51]];
        outgoing(&KEY, &mut offloaded, false);
        assert_eq!([offloaded[50], offloaded[51]], field);
    }

    /// F differs from one connection to the next (another port or address of the peer) and from
    /// one key to another, so that an ISN seen on one's own connection says nothing of F on
    /// another's (RFC 6528 §3).
    #[test]
    fn f_depends_on_every_end_and_the_key() {
        let base = offset(&KEY, MODULE, PC);
        let others = [
            offset(&KEY, MODULE, ([192, 168, 0, 10], 50_001)),
            offset(&KEY, MODULE, ([192, 168, 0, 11], 50_000)),
            offset(&KEY, ([192, 168, 0, 1], 502), PC),
            offset(&IsnKey::new(*b"another key 16 b"), MODULE, PC),
        ];
        for other in others {
            assert_ne!(other, base);
        }
        assert_eq!(offset(&KEY, MODULE, PC), base, "the same connection, the same F");
    }

    /// Frames that are not whole IPv4 TCP segments pass untouched, truncated ones included.
    #[test]
    fn other_frames_pass_untouched() {
        let whole = segment(MODULE, PC, 1000, 7, 0x12, &[]);
        for len in 0..whole.len() - 5 {
            let mut cut = whole[..len].to_vec();
            let before = cut.clone();
            outgoing(&KEY, &mut cut, true);
            incoming(&KEY, &mut cut);
            assert_eq!(cut, before, "cut at {len}");
        }
        let mut fragment = whole.clone();
        fragment[20] = 0x20; // more fragments
        let before = fragment.clone();
        outgoing(&KEY, &mut fragment, true);
        assert_eq!(fragment, before);
        let mut udp = whole.clone();
        udp[23] = 17;
        let before = udp.clone();
        incoming(&KEY, &mut udp);
        assert_eq!(udp, before);
        // Options that claim more than the header holds stop the walk, nothing past it changed.
        let mut odd = segment(PC, MODULE, 8, 9, ACK, &[SACK, 40, 0, 0]);
        incoming(&KEY, &mut odd);
        assert!(tcp_checksum_ok(&odd));
    }
}
