//! The discovery protocol's codec: arbitrary datagrams never panic a decoder; a request that
//! decodes re-encodes to the very same bytes (the format is canonical); and a request built
//! from arbitrary fields and encoded as the `remodaq` tool does decodes back to those fields.
//! `cargo +nightly fuzz run discovery_codec` (from the repository root).
#![no_main]

use libfuzzer_sys::fuzz_target;
use remodaq_protocol::access::{AllowList, Network, MAX_NETWORKS};
use remodaq_protocol::discovery::{
    decode_challenge, decode_info, decode_reply, decode_request, encode_request, Auth, Command, Request, MAX_DATAGRAM,
};
use remodaq_protocol::net::NetConfig;

/// Encodes a request as the `remodaq` tool does.
fn encode(id: u16, request: &Request) -> Option<Vec<u8>> {
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(id, request, &mut buf)?;
    Some(buf[..n].to_vec())
}

/// Takes up to `n` bytes off the front.
fn take<'a>(data: &mut &'a [u8], n: usize) -> &'a [u8] {
    let n = n.min(data.len());
    let (head, tail) = data.split_at(n);
    *data = tail;
    head
}

/// `N` bytes off the front (zeros past the end).
fn array<const N: usize>(data: &mut &[u8]) -> [u8; N] {
    let mut out = [0u8; N];
    let bytes = take(data, N);
    out[..bytes.len()].copy_from_slice(bytes);
    out
}

fuzz_target!(|data: &[u8]| {
    // Arbitrary bytes as a datagram.
    let _ = decode_info(data);
    let _ = decode_reply(data);
    let _ = decode_challenge(data);
    if let Some((id, request)) = decode_request(data) {
        assert_eq!(encode(id, &request).as_deref(), Some(data), "canonical: {request:?}");
    }
    // Arbitrary fields as a request.
    let mut rest = data;
    let [kind, count] = array::<2>(&mut rest);
    let id = u16::from_be_bytes(array::<2>(&mut rest));
    let mac = array::<6>(&mut rest);
    let auth = Auth { cnonce: array(&mut rest), snonce: array(&mut rest), proof: array(&mut rest) };
    let net = NetConfig {
        ip: array(&mut rest),
        mask: array(&mut rest),
        gateway: array(&mut rest),
        port: u16::from_be_bytes(array(&mut rest)),
    };
    let public = array::<32>(&mut rest);
    let sealed = array::<100>(&mut rest);
    let nets: Vec<Network> = (0..usize::from(count) % (MAX_NETWORKS + 1))
        .filter_map(|_| {
            let [a, b, c, d, prefix] = array::<5>(&mut rest);
            Network::new([a, b, c, d], prefix % 33)
        })
        .collect();
    let list = AllowList::of(&nets).expect("at most 4");
    let command = match kind % 5 {
        0 => Command::SetNetwork(net),
        1 => Command::Restart,
        2 => Command::GetAccess,
        3 => Command::SetAccess(list),
        _ => Command::SetPassword { public, sealed },
    };
    let request = match kind / 5 % 4 {
        0 => Request::Search,
        1 => Request::Identify { mac },
        2 => Request::Challenge { mac, cnonce: auth.cnonce },
        _ => Request::Command { mac, auth, command },
    };
    let bytes = encode(id, &request).expect("every request fits a datagram");
    assert_eq!(decode_request(&bytes), Some((id, request)), "round trip");
});
