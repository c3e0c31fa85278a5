//! The discovery / configuration protocol on the module side, without sockets.
mod common;

use common::{Live, S};

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use futures_executor::block_on;
use remodaq_shared::access::{AllowList, Network};
use remodaq_shared::discovery::{
    decode_info, decode_reply, decode_request, encode_request, info_flags, op, Effect, Identity, Request, Service,
    Status, Writer, MAX_DATAGRAM,
};
use remodaq_shared::net::NetConfig;
use remodaq_shared::password::PasswordHash;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::SettingsStore;

type Flash = RamFlash<4096, 1024>;

/// The map (behind its lock) and the store (behind its own).
struct Module {
    map: Mutex<NoopRawMutex, Live>,
    store: Mutex<CriticalSectionRawMutex, SettingsStore<Flash, S>>,
}

impl Module {
    fn settings(&self) -> S {
        block_on(self.map.lock()).0
    }

    /// From now on every commit fails (a flash whose writes fail).
    fn fail_commits(&mut self) {
        let mut flash = Flash::new();
        flash.set_budget(Some(0));
        *self.store.get_mut() =
            block_on(SettingsStore::open(flash, const { SettingsStore::<Flash, S>::config(0..4096) }));
    }
}

const MAC: [u8; 6] = [0x02, 0x11, 0x22, 0x33, 0x44, 0x55];
const OTHER: [u8; 6] = [0x02, 0x11, 0x22, 0x33, 0x44, 0x56];
const NEW_NET: NetConfig = NetConfig { ip: [10, 1, 2, 3], mask: [255, 255, 0, 0], gateway: [10, 1, 0, 1], port: 502 };

fn setup() -> (Service, Module) {
    let store = block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, S>::config(0..4096) }));
    let identity =
        Identity { model: 0x8318, name: "RemoDAQ-8318", version: 0xA100, mac: MAC, running: NetConfig::FACTORY };
    let settings = *store.get();
    (Service::new(identity), Module { map: Mutex::new(Live(settings)), store: Mutex::new(store) })
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

/// The administrator's PC.
const ADMIN: [u8; 4] = [192, 168, 0, 10];

fn ask(service: &mut Service, module: &mut Module, datagram: &[u8], now_ms: u64) -> Option<(Vec<u8>, Effect)> {
    ask_from(service, module, datagram, ADMIN, now_ms)
}

fn ask_from(
    service: &mut Service,
    module: &mut Module,
    datagram: &[u8],
    from: [u8; 4],
    now_ms: u64,
) -> Option<(Vec<u8>, Effect)> {
    let mut out = [0u8; MAX_DATAGRAM];
    block_on(service.handle(datagram, from, now_ms, &module.map, &module.store, &mut out))
        .map(|(n, e)| (out[..n].to_vec(), e))
}

fn status(reply: &[u8]) -> Status {
    decode_reply(reply).unwrap().status
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
        module.store.get_mut(),
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
    module.fail_commits();
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
        request(op::GET_ACCESS, 5, |w| {
            w.bytes(&MAC).string(b"remodaq");
        }),
        request(op::SET_ACCESS, 6, |w| {
            w.bytes(&MAC)
                .string(b"remodaq")
                .allow_list(&AllowList::of(&[Network::new([10, 0, 0, 0], 8).unwrap()]).unwrap());
        }),
    ]
}

#[test]
fn encode_request_writes_what_decode_request_reads() {
    let list = AllowList::of(&[Network::new([127, 0, 0, 2], 32).unwrap()]).unwrap();
    let requests = [
        Request::Search,
        Request::SetNetwork { mac: MAC, password: b"remodaq", net: NEW_NET },
        Request::Restart { mac: MAC, password: b"pw" },
        Request::Identify { mac: OTHER },
        Request::SetPassword { mac: MAC, password: b"old", new: b"new pass" },
        Request::GetAccess { mac: MAC, password: b"remodaq" },
        Request::SetAccess { mac: MAC, password: b"remodaq", list },
        Request::SetAccess { mac: MAC, password: b"remodaq", list: AllowList::EMPTY },
    ];
    for (id, r) in requests.iter().enumerate() {
        let mut buf = [0u8; MAX_DATAGRAM];
        let n = encode_request(id as u16, r, &mut buf).unwrap();
        assert_eq!(decode_request(&buf[..n]), Some((id as u16, *r)));
    }
    let mut buf = [0u8; MAX_DATAGRAM];
    assert_eq!(encode_request(1, &Request::Restart { mac: MAC, password: &[b'x'; 33] }, &mut buf), None);
}

#[test]
fn lock_out_is_kept_per_source() {
    let (mut service, mut module) = setup();
    let guesser = [192, 168, 0, 66];
    for _ in 0..6 {
        ask_from(&mut service, &mut module, &set_network(MAC, "guess", &NEW_NET), guesser, 1000);
    }
    let (reply, _) =
        ask_from(&mut service, &mut module, &set_network(MAC, "remodaq", &NEW_NET), guesser, 1500).unwrap();
    assert_eq!(status(&reply), Status::RateLimited, "the guessing host is locked out");
    let (reply, _) = ask(&mut service, &mut module, &set_network(MAC, "remodaq", &NEW_NET), 1500).unwrap();
    assert_eq!(status(&reply), Status::Ok, "the administrator elsewhere is not");
}

#[test]
fn allow_list_set_read_and_cleared_with_the_password() {
    let (mut service, mut module) = setup();
    let list =
        AllowList::of(&[Network::new([127, 0, 0, 2], 32).unwrap(), Network::new([10, 9, 0, 0], 16).unwrap()]).unwrap();
    let set = |password: &str, list: AllowList| {
        let mut buf = [0u8; MAX_DATAGRAM];
        let n =
            encode_request(5, &Request::SetAccess { mac: MAC, password: password.as_bytes(), list }, &mut buf).unwrap();
        buf[..n].to_vec()
    };
    let (reply, _) = ask(&mut service, &mut module, &set("wrong", list), 0).unwrap();
    assert_eq!(status(&reply), Status::WrongPassword);
    assert_eq!(module.settings().allow, AllowList::EMPTY);
    let (reply, _) = ask(&mut service, &mut module, &set("remodaq", list), 0).unwrap();
    assert_eq!(status(&reply), Status::Ok);
    assert_eq!(module.settings().allow, list, "in force at once");
    let search = request(op::SEARCH, 1, |_| {});
    let info = decode_info(&ask(&mut service, &mut module, &search, 0).unwrap().0).unwrap().flags;
    assert_eq!(info, Some(info_flags::WRITES_RESTRICTED), "a search shows that writes are restricted");
    let get = request(op::GET_ACCESS, 6, |w| {
        w.bytes(&MAC).string(b"remodaq");
    });
    let reply = decode_reply(&ask(&mut service, &mut module, &get, 0).unwrap().0).unwrap();
    assert_eq!((reply.status, reply.list), (Status::Ok, Some(list)));
    let wrong = request(op::GET_ACCESS, 6, |w| {
        w.bytes(&MAC).string(b"nope");
    });
    let reply = decode_reply(&ask(&mut service, &mut module, &wrong, 0).unwrap().0).unwrap();
    assert_eq!((reply.status, reply.list), (Status::WrongPassword, None), "the list needs the password");
    // Durable: the store has it.
    assert_eq!(block_on(module.store.lock()).get().allow, list);
    ask(&mut service, &mut module, &set("remodaq", AllowList::EMPTY), 0).unwrap();
    assert_eq!(module.settings().allow, AllowList::EMPTY);
    let info = decode_info(&ask(&mut service, &mut module, &search, 0).unwrap().0).unwrap().flags;
    assert_eq!(info, Some(0));
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
    let before = module.settings();
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
        let _ = decode_reply(&d);
        // Through the service, but never with the right password: nothing may change. Each
        // datagram comes 6 minutes after the last, longer than the longest lock-out (5 min),
        // so every command is really checked against the password, never just rate limited.
        if !d.windows(7).any(|w| w == b"remodaq") {
            if let Some((reply, _)) = ask(&mut service, &mut module, &d, i * 360_000) {
                if let Some(r) = decode_reply(&reply) {
                    let what = if r.opcode == op::IDENTIFY { "identify" } else { "command" };
                    *statuses.entry(format!("{what} {:?}", r.status)).or_insert(0u32) += 1;
                }
            }
        }
    }
    assert_eq!(module.settings(), before);
    // What the service answered: thousands of commands reached the password check and were
    // refused, none was locked out, and only identify (which needs no password) succeeded.
    assert_eq!(statuses.get("command RateLimited"), None, "{statuses:?}");
    assert_eq!(statuses.get("command Ok"), None, "{statuses:?}");
    assert!(statuses.get("command WrongPassword").copied().unwrap_or(0) > 5_000, "{statuses:?}");
}
