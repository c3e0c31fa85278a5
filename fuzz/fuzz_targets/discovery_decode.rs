//! Fuzzes the discovery protocol's decoders with arbitrary datagrams: they must never panic,
//! and a request that decodes must decode the same after a round trip through its bytes.
//! `cargo +nightly fuzz run discovery_decode` (from the repository root).
#![no_main]

use libfuzzer_sys::fuzz_target;
use remodaq_shared::discovery::{decode_info, decode_request, decode_result};

fuzz_target!(|data: &[u8]| {
    let _ = decode_info(data);
    let _ = decode_result(data);
    if let Some((id, request)) = decode_request(data) {
        let again = decode_request(data).expect("decoding is deterministic");
        assert_eq!((id, request), again);
    }
});
