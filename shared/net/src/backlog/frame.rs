//! The frame checks: a TCP segment (a SYN above all) read out of an Ethernet II frame, and
//! whether a frame is for this module and intact (its checksums).

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
pub(super) const FIN: u8 = 0x01;
pub(super) const SYN: u8 = 0x02;
pub(super) const RST: u8 = 0x04;
pub(super) const ACK: u8 = 0x10;

/// The client and TCP flags of `frame` if it is an Ethernet II frame carrying a whole IPv4 TCP
/// segment to `port`.
pub(super) fn segment_to(frame: &[u8], port: u16) -> Option<(Peer, u8)> {
    let (peer, destination, flags) = segment(frame)?;
    (destination == port).then_some((peer, flags))
}

/// The destination port of `frame` if it is an Ethernet II frame carrying a whole IPv4 TCP
/// segment.
pub fn destination_port(frame: &[u8]) -> Option<u16> {
    segment(frame).map(|(_, port, _)| port)
}

/// Where the TCP header of `frame` starts if it is an Ethernet II frame carrying an IPv4 TCP
/// segment, not a fragment (the frame checks of the backlog and of the keyed ISNs,
/// `crate::isn`).
pub(crate) fn tcp_at(frame: &[u8]) -> Option<usize> {
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
    (flags_offset & 0x3FFF == 0).then_some(14 + ihl)
}

/// The client, destination port and TCP flags of `frame` if it is an Ethernet II frame carrying
/// a whole IPv4 TCP segment.
fn segment(frame: &[u8]) -> Option<(Peer, u16, u8)> {
    let at = tcp_at(frame)?;
    let source = [*frame.get(26)?, *frame.get(27)?, *frame.get(28)?, *frame.get(29)?];
    // TCP (RFC 9293 §3.1): source port, destination port, ..., flags at byte 13.
    let tcp = frame.get(at..)?;
    let source_port = u16::from_be_bytes([*tcp.first()?, *tcp.get(1)?]);
    let destination_port = u16::from_be_bytes([*tcp.get(2)?, *tcp.get(3)?]);
    let flags = *tcp.get(13)?;
    Some((Peer { ip: source, port: source_port }, destination_port, flags))
}

/// A TCP segment as a frame carries it: its ports, flags and how many bytes of data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    /// Source port.
    pub source: u16,
    /// Destination port.
    pub destination: u16,
    /// TCP flags (RFC 9293 §3.1: FIN 0x01, SYN 0x02, RST 0x04, ACK 0x10).
    pub flags: u8,
    /// Data bytes: the IPv4 total length less both headers.
    pub data: usize,
}

impl Segment {
    /// Whether the segment ends its connection (FIN or RST).
    pub fn ends(&self) -> bool {
        self.flags & (FIN | RST) != 0
    }
}

/// The TCP segment `frame` carries, if it is an Ethernet II frame with a whole IPv4 TCP segment
/// (the QEMU board's measure of Modbus requests, which looks at both directions).
pub fn tcp_segment(frame: &[u8]) -> Option<Segment> {
    let at = tcp_at(frame)?;
    let (peer, destination, flags) = segment(frame)?;
    let total = usize::from(u16::from_be_bytes([*frame.get(16)?, *frame.get(17)?]));
    let offset = usize::from(frame.get(at + 12)? >> 4) * 4;
    let data = (14 + total).checked_sub(at + offset)?;
    Some(Segment { source: peer.port, destination, flags, data })
}

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
