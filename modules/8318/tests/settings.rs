//! The 8318's settings record: every field, set away from its factory value, survives encoding
//! and decoding (a restart), so no two fields share a tag (the credential once shared the
//! allow-list's: a password set was lost at the next start).

use remodaq_8318::settings::Settings;
use remodaq_protocol::auth::Credential;
use remodaq_shared::access::{AllowList, Network};
use remodaq_shared::net::NetConfig;
use remodaq_shared::settings::Counter;
use remodaq_shared::settings::{decode_record, encode_record, Schema};

#[test]
fn settings_round_trip() {
    let mut s = Settings::defaults();
    s.net = NetConfig { ip: [10, 1, 2, 3], mask: [255, 255, 0, 0], gateway: [10, 1, 0, 1], port: 502 };
    s.password = Credential { salt: [1; 16], iterations: 5000, stored_key: [2; 32], server_key: [3; 32] };
    s.input_type = 0x0E;
    s.cjc_offset = -123;
    s.enable_mask = 0x7F;
    s.downscale = true;
    s.allow = AllowList::of(&[Network::new([192, 168, 0, 0], 24).unwrap()]).unwrap();
    s.update = Counter { confirmed: 4, pending: 5 };
    let mut buf = [0u8; 448];
    let n = encode_record(&s, &mut buf).unwrap();
    assert_eq!(decode_record::<Settings>(&buf[..n]), Some(s));
}
