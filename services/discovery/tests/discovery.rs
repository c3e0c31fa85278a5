//! The discovery / configuration protocol on the module side, without sockets.
#[path = "../../../shared/tests/common/mod.rs"]
mod common;

use common::{Live, S};

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use futures_executor::block_on;
use remodaq_discovery::{
    decode_challenge, decode_info, decode_reply, decode_request, encode_request, info_flags, op, Auth, Command, Effect,
    Identity, Reply, Request, Service, Status, Writer, MAX_DATAGRAM,
};
use remodaq_protocol::auth;
use remodaq_protocol::discovery::client::{self, transact, Ask, Failure};
use remodaq_shared::access::{AllowList, Network};
use remodaq_shared::net::NetConfig;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::SettingsStore;

type Flash = RamFlash<4096, 1024>;

/// The map (behind its lock) and the store (behind its own).
struct Module {
    map: Mutex<NoopRawMutex, Live>,
    store: Mutex<CriticalSectionRawMutex, SettingsStore<Flash, S>>,
    _turn: std::sync::MutexGuard<'static, ()>,
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
/// Spec §1.4: a new module's network settings, as literals (not the code's constant).
const SPEC_FACTORY: NetConfig =
    NetConfig { ip: [192, 168, 0, 1], mask: [255, 255, 255, 0], gateway: [0, 0, 0, 0], port: 8000 };
const NEW_NET: NetConfig = NetConfig { ip: [10, 1, 2, 3], mask: [255, 255, 0, 0], gateway: [10, 1, 0, 1], port: 502 };

/// The module-wide guessing budget is one static: the tests of this file take turns, each
/// from a fresh budget.
static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn setup() -> (Service, Module) {
    let turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    remodaq_shared::password::AUTH.reset_budget_for_tests();
    let store = block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, S>::config(0..4096) }));
    let identity = Identity { model: 0x8318, name: "RemoDAQ-8318", version: 0xA100, mac: MAC, running: SPEC_FACTORY };
    let settings = *store.get();
    (Service::new(identity), Module { map: Mutex::new(Live(settings)), store: Mutex::new(store), _turn: turn })
}

fn request(opcode: u8, id: u16, build: impl FnOnce(&mut Writer<'_>)) -> Vec<u8> {
    let mut buf = [0u8; 256];
    let mut w = Writer::new(&mut buf, opcode, id);
    build(&mut w);
    let n = w.finish().unwrap();
    buf[..n].to_vec()
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

/// One authenticated command through the service (challenge, proof, answer), from `from` at
/// `now_ms`: the checked answer and the request sent.
fn run(
    service: &mut Service,
    module: &mut Module,
    from: [u8; 4],
    now_ms: u64,
    password: &str,
    what: Ask<'_>,
) -> Result<(Reply, Vec<u8>), Failure> {
    let send = |d: &[u8]| ask_from(service, module, d, from, now_ms).map(|(r, _)| r);
    transact(MAC, password.as_bytes(), what, [now_ms as u8; 16], 7, send)
}

fn status_of(result: Result<(Reply, Vec<u8>), Failure>) -> Status {
    result.expect("an answer").0.status
}

/// A password change to `new` (the PC's random numbers fixed).
fn set_password(new: &str) -> Ask<'_> {
    Ask::SetPassword { new: new.as_bytes(), salt: [0x21; 16], iterations: 4096, secret: [0x42; 32] }
}

/// The first 8 bytes of the SHA-256 of the repository's test key (keys/test-update.key.pub,
/// the key a build without REMODAQ_UPDATE_KEY takes), from the file.
fn test_key_fingerprint() -> [u8; 8] {
    use sha2::Digest;
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../keys/test-update.key.pub")).unwrap();
    let text = text.trim();
    let key: Vec<u8> = (0..32).map(|i| u8::from_str_radix(&text[2 * i..2 * i + 2], 16).unwrap()).collect();
    sha2::Sha256::digest(&key)[..8].try_into().unwrap()
}

#[test]
fn search_answers_identity_settings_and_flags() {
    let (mut service, mut module) = setup();
    let (reply, effect) = ask(&mut service, &mut module, &request(op::SEARCH, 0x1234, |_| {}), 65_432).unwrap();
    assert_eq!(effect, Effect::None);
    let info = decode_info(&reply).unwrap();
    assert_eq!((info.id, info.model, info.version, info.mac), (0x1234, 0x8318, 0xA100, MAC));
    assert_eq!(
        (info.running, info.stored, info.uptime_s, info.name),
        (SPEC_FACTORY, SPEC_FACTORY, 65, &b"RemoDAQ-8318"[..])
    );
    assert_eq!(info.flags, info_flags::FACTORY_PASSWORD, "a new module reports the factory password");
    if std::env::var_os("REMODAQ_UPDATE_KEY").is_none() {
        assert_eq!(info.update_key, test_key_fingerprint());
    }
}

#[test]
fn set_network_with_right_and_wrong_password() {
    let (mut service, mut module) = setup();
    let wrong = run(&mut service, &mut module, ADMIN, 0, "guess", Ask::SetNetwork(NEW_NET));
    assert_eq!(status_of(wrong), Status::WrongPassword);
    assert_eq!(module.settings().net, SPEC_FACTORY, "nothing changed");
    // The manuals' first contact: the factory password stores network settings.
    let (reply, request) = run(&mut service, &mut module, ADMIN, 1000, "remodaq", Ask::SetNetwork(NEW_NET)).unwrap();
    assert_eq!((reply.status, reply.mac), (Status::Ok, MAC));
    assert!(reply.signature.is_some(), "signed by the module");
    assert_eq!(module.settings().net, NEW_NET);
    assert!(!request.windows(7).any(|w| w == b"remodaq"), "no password on the wire");
    // Restart, with its effect.
    let mut effect = None;
    let mut send = |d: &[u8]| {
        let (r, e) = ask(&mut service, &mut module, d, 2000)?;
        effect = Some(e);
        Some(r)
    };
    let (reply, _) = transact(MAC, b"remodaq", Ask::Restart, [9; 16], 1, &mut send).unwrap();
    assert_eq!((reply.status, effect), (Status::Ok, Some(Effect::Restart)));
}

#[test]
fn replayed_and_altered_commands_change_nothing() {
    let (mut service, mut module) = setup();
    let (reply, set_network) = run(&mut service, &mut module, ADMIN, 0, "remodaq", Ask::SetNetwork(NEW_NET)).unwrap();
    assert_eq!(reply.status, Status::Ok);
    // Back to the factory settings, by the administrator.
    let (reply, _) = run(&mut service, &mut module, ADMIN, 100, "remodaq", Ask::SetNetwork(SPEC_FACTORY)).unwrap();
    assert_eq!(reply.status, Status::Ok);
    // The captured SET_NETWORK replayed (from anywhere, now or later): its nonce is spent.
    for (from, at) in [(ADMIN, 200), ([192, 168, 0, 66], 5_000)] {
        let (reply, effect) = ask_from(&mut service, &mut module, &set_network, from, at).unwrap();
        assert_eq!((status(&reply), effect), (Status::StaleNonce, Effect::None));
        assert_eq!(decode_reply(&reply).unwrap().signature, None);
        assert_eq!(module.settings().net, SPEC_FACTORY, "the replay changed nothing");
    }
    // Altered in flight (another address in the same request, a fresh nonce): the proof fails.
    let mut buf = [0u8; 256];
    let n = encode_request(3, &Request::Challenge { mac: MAC, cnonce: [1; 16] }, &mut buf).unwrap();
    let challenge = decode_challenge(&ask(&mut service, &mut module, &buf[..n], 300).unwrap().0).unwrap();
    let (client_key, _) = auth::derive(b"remodaq", &challenge.salt, challenge.iterations);
    let command = Command::SetNetwork(NEW_NET);
    let request = Request::Command {
        mac: MAC,
        auth: Auth { cnonce: [1; 16], snonce: challenge.snonce, proof: [0; 32] },
        command,
    };
    let n = encode_request(4, &request, &mut buf).unwrap();
    assert!(client::prove(&mut buf[..n], &client_key));
    let mut altered = buf[..n].to_vec();
    let ip_at = n - 14;
    altered[ip_at + 3] ^= 0x01;
    let (reply, _) = ask(&mut service, &mut module, &altered, 400).unwrap();
    assert_eq!(status(&reply), Status::WrongPassword);
    assert_eq!(module.settings().net, SPEC_FACTORY, "the altered request changed nothing");
    // And the original, sent after the altered one, finds its nonce spent too.
    let (reply, _) = ask(&mut service, &mut module, &buf[..n], 500).unwrap();
    assert_eq!(status(&reply), Status::StaleNonce);
    // A nonce expires after 30 s.
    let n = encode_request(5, &Request::Challenge { mac: MAC, cnonce: [2; 16] }, &mut buf).unwrap();
    let challenge = decode_challenge(&ask(&mut service, &mut module, &buf[..n], 1_000).unwrap().0).unwrap();
    let request = Request::Command {
        mac: MAC,
        auth: Auth { cnonce: [2; 16], snonce: challenge.snonce, proof: [0; 32] },
        command,
    };
    let n = encode_request(6, &request, &mut buf).unwrap();
    client::prove(&mut buf[..n], &client_key);
    let (reply, _) = ask(&mut service, &mut module, &buf[..n], 31_000).unwrap();
    assert_eq!(status(&reply), Status::StaleNonce);
    assert_eq!(module.settings().net, SPEC_FACTORY);
}

#[test]
fn a_forged_answer_is_recognised() {
    let (mut service, mut module) = setup();
    // A forger answers "ok" to a command that the module refused: the PC sees no signature of
    // the module on it.
    let mut send = |d: &[u8]| {
        let (mut reply, _) = ask(&mut service, &mut module, d, 0)?;
        if decode_reply(&reply).is_some_and(|r| r.status == Status::WrongPassword) {
            reply[14] = Status::Ok as u8;
            reply.push(0); // an empty allow-list
            reply.extend_from_slice(&[0xEE; 32]);
        }
        Some(reply)
    };
    assert_eq!(transact(MAC, b"guess", Ask::GetAccess, [3; 16], 1, &mut send).err(), Some(Failure::Forged));
}

#[test]
fn the_guessing_budget_is_module_wide() {
    let (mut service, mut module) = setup();
    // 10 wrong proofs, each from another (forged) source address.
    for i in 0..10u8 {
        let wrong = run(&mut service, &mut module, [10, 9, 9, i], 1_000, "guess", Ask::GetAccess);
        assert_eq!(status_of(wrong), Status::WrongPassword, "guess {i}");
    }
    // The 11th proof is not checked, whoever sends it: even the administrator's right one.
    let admin = run(&mut service, &mut module, ADMIN, 1_000, "remodaq", Ask::GetAccess);
    assert_eq!(status_of(admin), Status::RateLimited);
    // But only for the budget window: one proof more every 6 s.
    let admin = run(&mut service, &mut module, ADMIN, 7_000, "remodaq", Ask::GetAccess);
    assert_eq!(status_of(admin), Status::Ok);
    // Forged wrong guesses from the administrator's own address delay it by at most a minute.
    for _ in 0..20 {
        let _ = run(&mut service, &mut module, ADMIN, 8_000, "guess", Ask::GetAccess);
    }
    let admin = run(&mut service, &mut module, ADMIN, 8_000 + 60_000, "remodaq", Ask::GetAccess);
    assert_eq!(status_of(admin), Status::Ok, "no lock-out beyond the budget window");
}

#[test]
fn factory_password_then_a_sealed_password_change() {
    let (mut service, mut module) = setup();
    let list = AllowList::of(&[Network::new([192, 168, 0, 0], 24).unwrap()]).unwrap();
    // Allow-list changes wait for a password of the operator's own.
    let refused = run(&mut service, &mut module, ADMIN, 0, "remodaq", Ask::SetAccess(list));
    assert_eq!(status_of(refused), Status::SetPasswordFirst);
    assert_eq!(module.settings().allow, AllowList::EMPTY);
    // The change: a new credential sealed for the module; neither the password nor its keys
    // are on the wire.
    let new = "plant-7 secret";
    let (reply, request) = run(&mut service, &mut module, ADMIN, 100, "remodaq", set_password(new)).unwrap();
    assert_eq!(reply.status, Status::Ok);
    let (_, expected) = auth::derive(new.as_bytes(), &[0x21; 16], 4096);
    assert_eq!(module.settings().password, expected, "the module stores the new credential");
    for secret in [new.as_bytes(), &expected.stored_key, &expected.server_key] {
        assert!(!request.windows(secret.len()).any(|w| w == secret), "not on the wire");
    }
    let searched = ask(&mut service, &mut module, &request_search(), 200).unwrap().0;
    let info = decode_info(&searched).unwrap();
    assert_eq!(info.flags & info_flags::FACTORY_PASSWORD, 0);
    assert_eq!(status_of(run(&mut service, &mut module, ADMIN, 300, "remodaq", Ask::GetAccess)), Status::WrongPassword);
    assert_eq!(status_of(run(&mut service, &mut module, ADMIN, 400, new, Ask::SetAccess(list))), Status::Ok);
    let (reply, _) = run(&mut service, &mut module, ADMIN, 500, new, Ask::GetAccess).unwrap();
    assert_eq!((reply.status, reply.list), (Status::Ok, Some(list)));
    // The factory credential cannot be set back, nor a credential a module must not take. (The
    // factory password with another salt cannot be told from any other password: the module
    // never sees passwords; `remodaq password` refuses it.)
    let factory = Ask::SetPassword {
        new: auth::FACTORY_PASSWORD.as_bytes(),
        salt: auth::Credential::FACTORY.salt,
        iterations: 4096,
        secret: [3; 32],
    };
    assert_eq!(status_of(run(&mut service, &mut module, ADMIN, 600, new, factory)), Status::Invalid);
    let weak = Ask::SetPassword { new: b"whatever1", salt: [1; 16], iterations: 10, secret: [3; 32] };
    assert_eq!(status_of(run(&mut service, &mut module, ADMIN, 700, new, weak)), Status::Invalid);
    assert_eq!(module.settings().password, expected);
}

fn request_search() -> Vec<u8> {
    request(op::SEARCH, 1, |_| {})
}

#[test]
fn invalid_settings_and_failed_commits() {
    let (mut service, mut module) = setup();
    let bad = NetConfig { mask: [255, 0, 255, 0], ..NEW_NET };
    assert_eq!(status_of(run(&mut service, &mut module, ADMIN, 0, "remodaq", Ask::SetNetwork(bad))), Status::Invalid);
    // Modbus on another service's TCP port: the update service's (8301), the console's (its
    // factory port 80).
    for port in [8301, 80] {
        let clash = NetConfig { port, ..NEW_NET };
        let answer = run(&mut service, &mut module, ADMIN, 10, "remodaq", Ask::SetNetwork(clash));
        assert_eq!(status_of(answer), Status::Invalid, "port {port}");
    }
    assert_eq!(module.settings().net, SPEC_FACTORY);
    module.fail_commits();
    let failed = run(&mut service, &mut module, ADMIN, 100, "remodaq", Ask::SetNetwork(NEW_NET));
    assert_eq!(status_of(failed), Status::StoreFailed);
    assert_eq!(module.settings().net, SPEC_FACTORY, "the old settings stay in force");
}

#[test]
fn addressed_by_mac() {
    let (mut service, mut module) = setup();
    let mut buf = [0u8; 256];
    let n = encode_request(1, &Request::Challenge { mac: OTHER, cnonce: [0; 16] }, &mut buf).unwrap();
    assert!(ask(&mut service, &mut module, &buf[..n], 0).is_none(), "a challenge for another module");
    let n = encode_request(1, &Request::Identify { mac: OTHER }, &mut buf).unwrap();
    assert!(ask(&mut service, &mut module, &buf[..n], 0).is_none());
    let n = encode_request(1, &Request::Identify { mac: MAC }, &mut buf).unwrap();
    let (reply, effect) = ask(&mut service, &mut module, &buf[..n], 0).unwrap();
    assert_eq!((status(&reply), effect), (Status::Ok, Effect::Identify));
}

/// One valid datagram of each kind (the proofs are zeros: they are checked, and fail).
fn valid_requests() -> Vec<Vec<u8>> {
    let auth = Auth { cnonce: [1; 16], snonce: [2; 16], proof: [0; 32] };
    let list = AllowList::of(&[Network::new([10, 0, 0, 0], 8).unwrap()]).unwrap();
    let commands = [
        Command::SetNetwork(NEW_NET),
        Command::Restart,
        Command::GetAccess,
        Command::SetAccess(list),
        Command::SetAccess(AllowList::EMPTY),
        Command::SetPassword { public: [5; 32], sealed: [6; auth::SEALED_LEN] },
    ];
    let mut requests =
        vec![Request::Search, Request::Identify { mac: MAC }, Request::Challenge { mac: MAC, cnonce: [7; 16] }];
    requests.extend(commands.map(|command| Request::Command { mac: MAC, auth, command }));
    requests
        .iter()
        .map(|r| {
            let mut buf = [0u8; MAX_DATAGRAM];
            let n = encode_request(9, r, &mut buf).unwrap();
            assert_eq!(decode_request(&buf[..n]), Some((9, *r)), "round trip");
            buf[..n].to_vec()
        })
        .collect()
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
        if valid[5] != op::SET_ACCESS {
            assert_eq!(decode_request(&longer), None, "trailing byte");
        }
        let mut old_version = valid.clone();
        old_version[4] = 1;
        assert_eq!(decode_request(&old_version), None, "version 1 (passwords in clear) is not taken");
    }
    let mut oversized = valid_requests()[3].clone();
    oversized.resize(MAX_DATAGRAM + 1, 0);
    assert_eq!(decode_request(&oversized), None);
    // Replies are not requests.
    let (mut service, mut module) = setup();
    let (reply, _) = ask(&mut service, &mut module, &request_search(), 0).unwrap();
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
            let len = (next() % 260) as usize;
            (0..len).map(|_| next() as u8).collect::<Vec<u8>>()
        } else {
            valid[(next() % valid.len() as u64) as usize].clone()
        };
        for _ in 0..(next() % 4) {
            if !d.is_empty() {
                let at = (next() as usize) % d.len();
                d[at] = next() as u8;
            }
        }
        let _ = decode_request(&d);
        let _ = decode_info(&d);
        let _ = decode_reply(&d);
        let _ = decode_challenge(&d);
        if let Some((reply, _)) = ask(&mut service, &mut module, &d, i * 100) {
            if let Some(r) = decode_reply(&reply) {
                let what = if r.opcode == op::IDENTIFY { "identify" } else { "command" };
                *statuses.entry(format!("{what} {:?}", r.status)).or_insert(0u32) += 1;
            }
        }
    }
    assert_eq!(module.settings(), before);
    // Commands with nonces the module never handed out are refused before any proof check.
    assert_eq!(statuses.get("command Ok"), None, "{statuses:?}");
    assert!(statuses.get("command StaleNonce").copied().unwrap_or(0) > 5_000, "{statuses:?}");
}

/// A socket in memory: the datagrams to receive, in order (then nothing more, for ever), and
/// what was sent, with its destination.
struct Memory {
    incoming: std::collections::VecDeque<(Vec<u8>, [u8; 4], u16)>,
    sent: std::rc::Rc<std::cell::RefCell<Vec<[u8; 4]>>>,
}

impl remodaq_discovery::Datagrams for Memory {
    type Error = ();
    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), ()> {
        match self.incoming.pop_front() {
            Some((d, ip, port)) => {
                buf[..d.len()].copy_from_slice(&d);
                Ok((d.len(), ip, port))
            }
            None => core::future::pending().await,
        }
    }
    async fn send(&mut self, _: &[u8], ip: [u8; 4], _: u16) -> Result<(), ()> {
        self.sent.borrow_mut().push(ip);
        Ok(())
    }
}

/// Security review finding 12: a burst of searches from outside the module's subnet (answered
/// by broadcast, to a port the sender chose) gets at most `BROADCAST_BURST` broadcasts; a
/// search from inside the subnet is still answered to its sender.
#[test]
fn broadcast_answers_to_another_subnet_are_bounded() {
    use remodaq_discovery::{serve, BROADCAST_BURST};
    let (_, module) = setup();
    let identity = Identity { model: 0x8318, name: "RemoDAQ-8318", version: 0xA100, mac: MAC, running: SPEC_FACTORY };
    let search = request(op::SEARCH, 7, |_| {});
    let mut incoming: std::collections::VecDeque<_> = (0..50).map(|_| (search.clone(), [10, 6, 6, 6], 9999)).collect();
    incoming.push_back((search.clone(), ADMIN, 50000));
    let total = incoming.len();
    let sent = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
    let mut socket = Memory { incoming, sent: sent.clone() };
    let served = serve(&mut socket, &module.map, &module.store, identity, async |_| {});
    let watched = async {
        // Every datagram taken (the in-subnet one last), then done.
        while !sent.borrow().contains(&ADMIN) {
            embassy_futures::yield_now().await;
        }
    };
    block_on(embassy_futures::select::select(served, watched));
    let sent = sent.borrow();
    let broadcasts = sent.iter().filter(|ip| **ip == [255; 4]).count();
    assert_eq!(broadcasts, BROADCAST_BURST as usize, "{total} requests: {sent:?}");
    assert_eq!(sent.iter().filter(|ip| **ip == ADMIN).count(), 1, "the administrator on the subnet is answered");
}

/// Security review finding 1: the factory password is public, so on an unclaimed module anyone
/// may prove it. Alternating network settings under it commit a burst of 20 (docs/security.md,
/// "Flash wear"), then each is refused with its own status, changes nothing and is counted in
/// register 40256 (the diagnostics' commit-budget refusals).
#[test]
fn commits_under_the_public_factory_password_draw_on_a_budget() {
    use remodaq_shared::diagnostics::DIAGNOSTICS;
    use remodaq_shared::protocol::diag::Diag;
    let (mut service, mut module) = setup();
    let refusals_before = DIAGNOSTICS.read(Diag::WriteBudgetRefusals, 0);
    let nets = [NetConfig { port: 8001, ..NEW_NET }, NetConfig { port: 8002, ..NEW_NET }];
    let mut statuses = Vec::new();
    for n in 0..30u64 {
        // The burst alternates; beyond it, each asks for the setting not in force.
        let net = nets[(n.min(20) % 2) as usize];
        statuses.push(status_of(run(&mut service, &mut module, ADMIN, 1000 + n, "remodaq", Ask::SetNetwork(net))));
    }
    let ok = statuses.iter().take_while(|s| **s == Status::Ok).count();
    assert_eq!(ok, 20, "the burst: {statuses:?}");
    assert!(statuses[20..].iter().all(|s| *s == Status::CommitBudget), "then refused: {statuses:?}");
    // The 20th change (n = 19, port 8002) is the last one in force.
    assert_eq!(module.settings().net, nets[1], "a refusal changes nothing");
    let refusals = DIAGNOSTICS.read(Diag::WriteBudgetRefusals, 0).wrapping_sub(refusals_before);
    assert_eq!(refusals, 10, "each refusal counted");
}

/// Security review finding 8: a credential sealed for another key than the one the module
/// agreed (a key a man in the middle swapped into the CHALLENGE answer, or an older one) opened
/// to random bytes, which passed as a credential about once in 430 tries and locked the module.
/// Here the worst case, made on purpose: a body that decrypts to a usable credential under the
/// module's key, but whose key confirmation was made with another; refused (status 3), nothing
/// stored. The same body with its own confirmation is then stored: the key agreed was kept.
#[test]
fn a_password_sealed_for_another_key_is_refused() {
    use remodaq_protocol::auth::{derive, seal_credential, x25519, Credential, BASE_POINT, CREDENTIAL_LEN};
    use remodaq_protocol::discovery::{client, Auth as WireAuth, SEAL_LABEL};
    let (mut service, mut module) = setup();
    let (_, new) = derive(b"a password of mine", &[0x21; 16], 4096);
    let secret = [0x42; 32];
    let attempt = |service: &mut Service, module: &mut Module, n: u8, tag_from_another_key: bool| -> Status {
        let cnonce = [n; 16];
        let mut buf = [0u8; 256];
        let len = encode_request(1, &Request::Challenge { mac: MAC, cnonce }, &mut buf).unwrap();
        let (reply, _) = ask(service, module, &buf[..len], 1000).unwrap();
        let challenge = decode_challenge(&reply).unwrap();
        let context: [&[u8]; 3] = [SEAL_LABEL, &cnonce, &challenge.snonce];
        let mut sealed = seal_credential(&x25519(&secret, &challenge.public), &context, &new);
        if tag_from_another_key {
            let other = seal_credential(&x25519(&secret, &x25519(&[0x77; 32], &BASE_POINT)), &context, &new);
            sealed[CREDENTIAL_LEN..].copy_from_slice(&other[CREDENTIAL_LEN..]);
        }
        let command = Command::SetPassword { public: x25519(&secret, &BASE_POINT), sealed };
        let auth = WireAuth { cnonce, snonce: challenge.snonce, proof: [0; 32] };
        let len = encode_request(2, &Request::Command { mac: MAC, auth, command }, &mut buf).unwrap();
        let (client_key, _) = derive(b"remodaq", &challenge.salt, challenge.iterations);
        assert!(client::prove(&mut buf[..len], &client_key));
        let (answer, _) = ask(service, module, &buf[..len], 1001).unwrap();
        status(&answer)
    };
    assert_eq!(attempt(&mut service, &mut module, 1, true), Status::Invalid, "confirmed with another key");
    assert_eq!(module.settings().password, Credential::FACTORY, "nothing stored");
    assert_eq!(attempt(&mut service, &mut module, 2, false), Status::Ok, "the same, confirmed with the key agreed");
    assert_eq!(module.settings().password, new);
}
