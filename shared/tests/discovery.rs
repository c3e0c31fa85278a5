//! The discovery / configuration protocol on the module side, without sockets.

use futures_executor::block_on;
use remodaq_shared::discovery::{
    decode_info, decode_request, decode_result, op, Effect, Identity, Service, Status, Writer, MAX_DATAGRAM,
};
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::net::{NetConfig, NetRecord};
use remodaq_shared::password::PasswordHash;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema, SettingsStore, StoreError};

type Flash = RamFlash<4096, 1024>;

#[derive(Clone, Copy, PartialEq, Debug)]
struct S {
    net: NetConfig,
    password: PasswordHash,
}

impl Schema for S {
    const VERSION: u8 = 1;
    fn defaults() -> Self {
        Self { net: NetConfig::FACTORY, password: PasswordHash::factory() }
    }
    fn encode(&self, w: &mut RecordWriter<'_>) {
        self.net.encode(w);
        self.password.encode(w);
    }
    fn decode(_: u8, r: &RecordReader<'_>) -> Self {
        Self { net: NetConfig::decode(r), password: PasswordHash::decode(r) }
    }
}

remodaq_shared::impl_common_settings!(S);

struct Module {
    store: SettingsStore<Flash, S>,
    fail_commits: bool,
}

impl SettingsAccess for Module {
    type Settings = S;
    fn settings(&self) -> &S {
        self.store.get()
    }
    async fn commit(&mut self, s: S) -> Result<(), StoreError> {
        if self.fail_commits {
            return Err(StoreError::Flash);
        }
        self.store.commit(s).await
    }
}

const MAC: [u8; 6] = [0x02, 0x11, 0x22, 0x33, 0x44, 0x55];
const OTHER: [u8; 6] = [0x02, 0x11, 0x22, 0x33, 0x44, 0x56];
const NEW_NET: NetConfig = NetConfig { ip: [10, 1, 2, 3], mask: [255, 255, 0, 0], gateway: [10, 1, 0, 1], port: 502 };

fn setup() -> (Service, Module) {
    let store = block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, S>::config(0..4096) }));
    let identity =
        Identity { model: 0x8318, name: "RemoDAQ-8318", version: 0xA100, mac: MAC, running: NetConfig::FACTORY };
    (Service::new(identity), Module { store, fail_commits: false })
}

fn request(opcode: u8, id: u16, build: impl FnOnce(&mut Writer<'_>)) -> Vec<u8> {
    let mut buf = [0u8; 256];
    let mut w = Writer::new(&mut buf, opcode, id);
    build(&mut w);
    let n = w.finish().unwrap();
    buf[..n].to_vec()
}

fn set_network(mac: [u8; 6], password: &str, net: &NetConfig) -> Vec<u8> {
    request(op::SET_NETWORK, 7, |w| {
        w.bytes(&mac).string(password.as_bytes()).net(net);
    })
}

fn ask(service: &mut Service, module: &mut Module, datagram: &[u8], now_ms: u64) -> Option<(Vec<u8>, Effect)> {
    let mut out = [0u8; MAX_DATAGRAM];
    block_on(service.handle(datagram, now_ms, module, &mut out)).map(|(n, e)| (out[..n].to_vec(), e))
}

fn status(reply: &[u8]) -> Status {
    decode_result(reply).unwrap().3
}

#[test]
fn search_answers_identity_and_settings() {
    let (mut service, mut module) = setup();
    let (reply, effect) = ask(&mut service, &mut module, &request(op::SEARCH, 0x1234, |_| {}), 65_432).unwrap();
    assert_eq!(effect, Effect::None);
    let info = decode_info(&reply).unwrap();
    assert_eq!((info.id, info.model, info.version, info.mac), (0x1234, 0x8318, 0xA100, MAC));
    assert_eq!(
        (info.running, info.stored, info.uptime_s, info.name),
        (NetConfig::FACTORY, NetConfig::FACTORY, 65, &b"RemoDAQ-8318"[..])
    );
}

#[test]
fn set_network_with_right_and_wrong_password() {
    let (mut service, mut module) = setup();
    let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "wrong", &NEW_NET), 0).unwrap();
    assert_eq!(status(&reply), Status::WrongPassword);
    assert_eq!(module.settings().net, NetConfig::FACTORY, "nothing changed");
    let (reply, effect) = ask(&mut service, &mut module, &set_network(MAC, "remodaq", &NEW_NET), 0).unwrap();
    assert_eq!((status(&reply), effect), (Status::Ok, Effect::None));
    assert_eq!(module.settings().net, NEW_NET);
    // Stored, not yet running: SEARCH shows both.
    let (reply, _) = ask(&mut service, &mut module, &request(op::SEARCH, 1, |_| {}), 0).unwrap();
    let info = decode_info(&reply).unwrap();
    assert_eq!((info.running, info.stored), (NetConfig::FACTORY, NEW_NET));
    // Durable: a new store on the same flash has it.
    let flash = std::mem::replace(
        &mut module.store,
        block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, S>::config(0..4096) })),
    )
    .into_flash();
    let store = block_on(SettingsStore::<Flash, S>::open(flash, const { SettingsStore::<Flash, S>::config(0..4096) }));
    assert_eq!(store.get().net, NEW_NET);
}

#[test]
fn invalid_settings_and_failed_commits() {
    let (mut service, mut module) = setup();
    let bad = NetConfig { mask: [255, 0, 255, 0], ..NEW_NET };
    let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "remodaq", &bad), 0).unwrap();
    assert_eq!(status(&reply), Status::Invalid);
    module.fail_commits = true;
    let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "remodaq", &NEW_NET), 0).unwrap();
    assert_eq!(status(&reply), Status::StoreFailed);
    assert_eq!(module.settings().net, NetConfig::FACTORY);
}

#[test]
fn addressed_by_mac() {
    let (mut service, mut module) = setup();
    assert!(ask(&mut service, &mut module, &set_network(OTHER, "remodaq", &NEW_NET), 0).is_none());
    let restart = |mac: [u8; 6]| {
        request(op::RESTART, 3, |w| {
            w.bytes(&mac).string(b"remodaq");
        })
    };
    assert!(ask(&mut service, &mut module, &restart(OTHER), 0).is_none());
    let (reply, effect) = ask(&mut service, &mut module, &restart(MAC), 0).unwrap();
    assert_eq!((status(&reply), effect), (Status::Ok, Effect::Restart));
    let identify = |mac: [u8; 6]| {
        request(op::IDENTIFY, 4, |w| {
            w.bytes(&mac);
        })
    };
    assert!(ask(&mut service, &mut module, &identify(OTHER), 0).is_none());
    assert_eq!(ask(&mut service, &mut module, &identify(MAC), 0).unwrap().1, Effect::Identify);
}

#[test]
fn wrong_guesses_are_rate_limited() {
    let (mut service, mut module) = setup();
    for _ in 0..3 {
        let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "guess", &NEW_NET), 1000).unwrap();
        assert_eq!(status(&reply), Status::WrongPassword);
    }
    let (reply, effect) = ask(
        &mut service,
        &mut module,
        &request(op::RESTART, 3, |w| {
            w.bytes(&MAC).string(b"remodaq");
        }),
        1500,
    )
    .unwrap();
    assert_eq!((status(&reply), effect), (Status::RateLimited, Effect::None), "locked, even with the right password");
    let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "remodaq", &NEW_NET), 2000).unwrap();
    assert_eq!(status(&reply), Status::Ok, "after the lock-out");
}

#[test]
fn password_change() {
    let (mut service, mut module) = setup();
    let change = |old: &str, new: &str| {
        request(op::SET_PASSWORD, 9, |w| {
            w.bytes(&MAC).string(old.as_bytes()).string(new.as_bytes());
        })
    };
    let (reply, _) = ask(&mut service, &mut module, &change("remodaq", "abc"), 0).unwrap();
    assert_eq!(status(&reply), Status::Invalid, "too short");
    let (reply, _) = ask(&mut service, &mut module, &change("remodaq", "plant-7 secret"), 0).unwrap();
    assert_eq!(status(&reply), Status::Ok);
    assert!(module.settings().password.matches(b"plant-7 secret"));
    assert_ne!(module.settings().password, PasswordHash::new([0; 16], b"plant-7 secret"), "salted");
    let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "remodaq", &NEW_NET), 0).unwrap();
    assert_eq!(status(&reply), Status::WrongPassword, "the old password no longer works");
    let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "plant-7 secret", &NEW_NET), 0).unwrap();
    assert_eq!(status(&reply), Status::Ok);
}

/// Every valid request, whole.
fn valid_requests() -> Vec<Vec<u8>> {
    vec![
        request(op::SEARCH, 1, |_| {}),
        set_network(MAC, "remodaq", &NEW_NET),
        request(op::RESTART, 2, |w| {
            w.bytes(&MAC).string(b"remodaq");
        }),
        request(op::IDENTIFY, 3, |w| {
            w.bytes(&MAC);
        }),
        request(op::SET_PASSWORD, 4, |w| {
            w.bytes(&MAC).string(b"remodaq").string(b"newpass1");
        }),
    ]
}

#[test]
fn truncated_extended_and_oversized_datagrams_are_ignored_without_side_effects() {
    for valid in valid_requests() {
        assert!(decode_request(&valid).is_some());
        for cut in 0..valid.len() {
            assert_eq!(decode_request(&valid[..cut]), None, "truncated at {cut}: {valid:02x?}");
        }
        let mut longer = valid.clone();
        longer.push(0);
        assert_eq!(decode_request(&longer), None, "trailing byte");
        let mut wrong_version = valid.clone();
        wrong_version[4] = 2;
        assert_eq!(decode_request(&wrong_version), None);
    }
    let mut oversized = set_network(MAC, "remodaq", &NEW_NET);
    oversized.resize(MAX_DATAGRAM + 1, 0);
    assert_eq!(decode_request(&oversized), None);
    // A password length byte beyond the limit.
    let long_password = request(op::RESTART, 2, |w| {
        w.bytes(&MAC).string(&[b'x'; 40]);
    });
    assert_eq!(decode_request(&long_password), None);
    // Replies are not requests.
    let (mut service, mut module) = setup();
    let (reply, _) = ask(&mut service, &mut module, &request(op::SEARCH, 1, |_| {}), 0).unwrap();
    assert_eq!(decode_request(&reply), None);
    assert!(ask(&mut service, &mut module, &reply, 0).is_none());
}

#[test]
fn random_and_mutated_datagrams_never_panic_nor_change_settings() {
    let (mut service, mut module) = setup();
    let before = *module.settings();
    let mut seed = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let valid = valid_requests();
    let mut statuses = std::collections::BTreeMap::new();
    for i in 0..200_000u64 {
        let mut d = if i % 2 == 0 {
            let len = (next() % 200) as usize;
            (0..len).map(|_| next() as u8).collect::<Vec<u8>>()
        } else {
            valid[(next() % valid.len() as u64) as usize].clone()
        };
        // Mutate: flip a few bytes (keeping most of the structure).
        for _ in 0..(next() % 4) {
            if !d.is_empty() {
                let at = (next() as usize) % d.len();
                d[at] = next() as u8;
            }
        }
        let _ = decode_request(&d);
        let _ = decode_info(&d);
        let _ = decode_result(&d);
        // Through the service, but never with the right password: nothing may change. Each
        // datagram comes 6 minutes after the last, longer than the longest lock-out (5 min),
        // so every command is really checked against the password, never just rate limited.
        if !d.windows(7).any(|w| w == b"remodaq") {
            if let Some((reply, _)) = ask(&mut service, &mut module, &d, i * 360_000) {
                if let Some((opcode, _, _, status)) = decode_result(&reply) {
                    let what = if opcode == op::IDENTIFY { "identify" } else { "command" };
                    *statuses.entry(format!("{what} {status:?}")).or_insert(0u32) += 1;
                }
            }
        }
    }
    assert_eq!(*module.settings(), before);
    // What the service answered: thousands of commands reached the password check and were
    // refused, none was locked out, and only identify (which needs no password) succeeded.
    assert_eq!(statuses.get("command RateLimited"), None, "{statuses:?}");
    assert_eq!(statuses.get("command Ok"), None, "{statuses:?}");
    assert!(statuses.get("command WrongPassword").copied().unwrap_or(0) > 5_000, "{statuses:?}");
}
