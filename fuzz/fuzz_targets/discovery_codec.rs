//! The discovery protocol's codec: arbitrary datagrams never panic a decoder; a request that
//! decodes re-encodes to the very same bytes (the format is canonical); and a request built
//! from arbitrary fields and encoded as the `remodaq` tool does decodes back to those fields.
//! `cargo +nightly fuzz run discovery_codec` (from the repository root).
#![no_main]

use libfuzzer_sys::fuzz_target;
use remodaq_protocol::access::{AllowList, Network, MAX_NETWORKS};
use remodaq_protocol::discovery::{
    decode_info, decode_reply, decode_request, encode_request, Request, MAX_DATAGRAM, MAX_PASSWORD_LEN,
};
use remodaq_protocol::net::NetConfig;

/// Encodes a request as the `remodaq` tool does.
fn encode(id: u16, request: &Request<'_>) -> Option<Vec<u8>> {
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
    if let Some((id, request)) = decode_request(data) {
        assert_eq!(encode(id, &request).as_deref(), Some(data), "canonical: {request:?}");
    }
    // Arbitrary fields as a request.
    let mut rest = data;
    let [kind, pw_len, new_len] = array::<3>(&mut rest);
    let id = u16::from_be_bytes(array::<2>(&mut rest));
    let mac = array::<6>(&mut rest);
    let net = NetConfig {
        ip: array(&mut rest),
        mask: array(&mut rest),
        gateway: array(&mut rest),
        port: u16::from_be_bytes(array(&mut rest)),
    };
    let password = take(&mut rest, usize::from(pw_len) % (MAX_PASSWORD_LEN + 1));
    let new = take(&mut rest, usize::from(new_len) % (MAX_PASSWORD_LEN + 1));
    let nets: Vec<Network> = (0..usize::from(new_len) % (MAX_NETWORKS + 1))
        .filter_map(|_| {
            let [a, b, c, d, prefix] = array::<5>(&mut rest);
            Network::new([a, b, c, d], prefix % 33)
        })
        .collect();
    let list = AllowList::of(&nets).expect("at most 4");
    let request = match kind % 7 {
        0 => Request::Search,
        1 => Request::SetNetwork { mac, password, net },
        2 => Request::Restart { mac, password },
        3 => Request::Identify { mac },
        4 => Request::SetPassword { mac, password, new },
        5 => Request::GetAccess { mac, password },
        _ => Request::SetAccess { mac, password, list },
    };
    let bytes = encode(id, &request).expect("every request fits a datagram");
    assert_eq!(decode_request(&bytes), Some((id, request)), "round trip");
});
