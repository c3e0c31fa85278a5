//! The web console's API (remodaq_web::service, docs/web.md) with both modules' real register
//! maps: the input is an HTTP request as bytes, parsed by picoserve within the module's buffer
//! and answered by the API, as the host build serves it. Invariants: an answer is an HTTP/1.1
//! status line with a known status and, when it is JSON, valid JSON; and nothing the module
//! keeps changes (settings, outputs, the flags Modbus clears by reading), since no fuzzed
//! request can carry a session's signature. A first byte with bit 7 set fuzzes the JSON of a
//! write instead: the write request built from a body for a field picked by the second byte
//! only ever addresses that field's registers, with a function that suits its format; with
//! bits 7 and 6 set, the JSON of the network settings and of the allow-list, whose accepted
//! values must be usable ones.
//! `cargo +nightly fuzz run web_api` (from the repository root).
#![no_main]

use core::cell::{Cell, RefCell};

use embassy_futures::block_on;
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embassy_sync::mutex::Mutex;
use libfuzzer_sys::fuzz_target;
use picoserve::{Config, Router, Timeouts};
use remodaq_protocol::resources::{self, Format};
use remodaq_shared::identity::Identity;
use remodaq_shared::json::Value;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::password::AUTH;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{Schema, SettingsStore};
use remodaq_web::service::{write_request, Api, SharedSessions};
use remodaq_web::Sessions;

type Flash = RamFlash<{ 64 * 1024 }, { 16 * 1024 }>;

/// The host build's request buffer (boards/host/src/web.rs).
const HTTP_BUFFER: usize = 2048;

static CONFIG: Config = Config::new(Timeouts {
    start_read_request: embassy_time::Duration::from_secs(5),
    persistent_start_read_request: embassy_time::Duration::from_secs(1),
    read_request: embassy_time::Duration::from_secs(3),
    write: embassy_time::Duration::from_secs(1),
})
.close_connection_after_response();

/// The request's bytes, read in pieces of at most 7 bytes (a request split across reads), and
/// what the module sent: the web tests' connection in memory.
#[path = "../../services/web/tests/common/memory_connection.rs"]
mod memory_connection;
use memory_connection::Connection;

fn now_ms() -> u64 {
    embassy_time::Instant::now().as_millis()
}

/// Serves one connection carrying `request`; what the module answered.
fn serve<M: RegisterMap + SettingsAccess>(
    map: &Mutex<NoopRawMutex, M>,
    store: &Mutex<CriticalSectionRawMutex, SettingsStore<Flash, M::Settings>>,
    model: u16,
    request: &[u8],
) -> Vec<u8> {
    static SESSIONS: SharedSessions = Blocking::new(RefCell::new(Sessions::new()));
    let identity = Identity {
        model,
        version: 0xA100,
        name: "fuzz",
        mac: [2, 0, 0, 0, 0, 1],
        running: remodaq_protocol::net::NetConfig::FACTORY,
    };
    let restart = Cell::new(false);
    let api = Api { map, store, identity, sessions: &SESSIONS, peer: [127, 0, 0, 1], now_ms, restart: &restart };
    let app = Router::from_service(api);
    let mut buffer = [0u8; HTTP_BUFFER];
    let mut output = Vec::new();
    let connection = Connection { input: request, output: &mut output, piece: 7 };
    let _ = block_on(
        picoserve::Server::custom(&app, picoserve::time::EmbassyTimer, &CONFIG, &mut buffer).serve(connection),
    );
    assert!(!restart.get(), "a fuzzed request asked for a restart");
    output
}

/// The invariants of an answer.
fn check(answer: &[u8]) {
    if answer.is_empty() {
        return;
    }
    let text = String::from_utf8_lossy(answer);
    let (head, body) = text.split_once("\r\n\r\n").expect("a head and a body");
    let status: u16 =
        head.strip_prefix("HTTP/1.1 ").and_then(|r| r.get(..3)).and_then(|c| c.parse().ok()).expect("status");
    assert!(
        [200, 202, 204, 400, 401, 403, 404, 405, 408, 409, 413, 414, 421, 422, 429, 431, 500, 503].contains(&status),
        "status {status}: {head}"
    );
    if head.contains("application/json") && status != 204 {
        serde_json::from_str::<serde_json::Value>(body).unwrap_or_else(|e| panic!("not JSON ({e}): {body}"));
    }
}

fn store<S: Schema + Copy>() -> Mutex<CriticalSectionRawMutex, SettingsStore<Flash, S>> {
    Mutex::new(block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, S>::config(0..64 * 1024) })))
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else { return };
    if !AUTH.is_seeded() {
        AUTH.seed(&[7; 32]);
    }
    if which & 0xC0 == 0xC0 {
        // The JSON of the network settings and of the allow-list: what is taken is usable.
        if let Ok((net, http_port)) = remodaq_web::settings::network_of(rest) {
            assert!(net.is_valid(), "{net:?}");
            assert!(http_port != 0 && http_port != net.port, "{http_port}");
        }
        if let Some(list) = remodaq_web::settings::allow_list_of(rest) {
            assert!(list.iter().all(|n| n.prefix <= 32));
        }
        return;
    }
    if which & 0x80 != 0 {
        // The JSON of a write, for one field of one resource.
        let Some((&pick, body)) = rest.split_first() else { return };
        let all: Vec<_> = resources::M8318
            .iter()
            .chain(resources::M8350)
            .flat_map(|r| r.fields.iter().map(move |f| (r, f)))
            .collect();
        let (r, f) = all[usize::from(pick) % all.len()];
        // The module's JSON reader takes nothing that is not JSON (serde_json as the oracle),
        // and reads the same members.
        if let Some(object) = remodaq_shared::json::Object::parse(body) {
            let full: serde_json::Map<String, serde_json::Value> =
                serde_json::from_slice(body).expect("a body the reader took is a JSON object");
            for (name, value) in &full {
                let got = object.get(name);
                match (value, got) {
                    (serde_json::Value::String(s), Some(Value::Str(t))) => assert_eq!(s, t),
                    (serde_json::Value::Bool(b), Some(Value::Bool(c))) => assert_eq!(*b, c),
                    (serde_json::Value::Null, Some(Value::Null)) => {}
                    (serde_json::Value::Number(_), Some(Value::Number(_))) => {}
                    (serde_json::Value::Array(a), Some(Value::Strings(_))) => {
                        let read: Vec<&str> = object.strings(name).expect("strings").collect();
                        assert_eq!(a.iter().map(|v| v.as_str().expect("a string")).collect::<Vec<_>>(), read);
                    }
                    other => panic!("member {name}: {other:?}"),
                }
            }
        }
        let n = u16::from(which & 0x0F) % r.count.max(1);
        if let Ok(pdu) = write_request(f, n, body) {
            let b = pdu.bytes();
            let addr = u16::from_be_bytes([b[1], b[2]]);
            assert_eq!(addr, f.addr(n), "{}.{}", r.name, f.name);
            let expected = match f.format {
                Format::Bool => 0x05,
                Format::Long => 0x10,
                _ => 0x06,
            };
            assert_eq!(b[0], expected, "{}.{}", r.name, f.name);
            assert!(f.writable);
            if expected == 0x05 {
                assert!(matches!([b[3], b[4]], [0xFF, 0] | [0, 0]));
            }
        }
        return;
    }
    if which & 1 == 0 {
        type Settings = remodaq_8318::settings::Settings;
        let store = store::<Settings>();
        let settings = *block_on(store.lock()).get();
        let map = Mutex::new(remodaq_8318::map::Map8318::new(&store, &settings));
        check(&serve(&map, &store, 0x8318, rest));
        assert!(*block_on(store.lock()).get() == settings, "a fuzzed request changed a setting");
    } else {
        type Settings = remodaq_8350::settings::Settings;
        let store = store::<Settings>();
        let settings = *block_on(store.lock()).get();
        let io = remodaq_8350::io::IoCell::<NoopRawMutex>::new(RefCell::new(remodaq_8350::io::Io::new(
            remodaq_8350::di::SAMPLE_RATE_HZ,
            &settings,
        )));
        remodaq_8350::io::with(&io, |s| s.di.process(&[0, 0xFFF, 0, 0xA5A, 0x5A5]));
        let before = remodaq_8350::io::with(&io, |s| (s.di.flags(), s.pulse.do_bits()));
        let map = Mutex::new(remodaq_8350::map::Map8350::new(&store, &settings, &io));
        check(&serve(&map, &store, 0x8350, rest));
        assert!(*block_on(store.lock()).get() == settings, "a fuzzed request changed a setting");
        let after = remodaq_8350::io::with(&io, |s| (s.di.flags(), s.pulse.do_bits()));
        assert_eq!(before, after, "a fuzzed request changed the outputs or cleared a flag");
    }
});
