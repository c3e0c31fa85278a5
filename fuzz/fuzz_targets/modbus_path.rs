//! The whole Modbus path through both modules' real register maps: the input is a byte stream
//! (its first byte picks the module), cut into frames by the real framing and answered by the
//! real engine, as the connection server does. Invariants of every answer: it echoes the
//! request's transaction and unit ids and function code, or sets bit 7 with exception 1 to 4
//! and nothing more; it fits a PDU; a read answers exactly the quantity asked; a write echoes
//! the request's start and quantity (or value); an answered request only touched addresses that
//! the protocol crate's decoding maps for that access. The maps' own rules (the 8350's extra pulses,
//! flags cleared on read, settings committed to a RAM flash, the diagnostics registers) run as
//! on the module. The second byte sets the scene: the client's address (127.0.0.1 or
//! 127.0.0.2), a write allow-list of 127.0.0.2/32 (extensions §4), and on the 8350 a host
//! watchdog armed and tripped before the stream (its writes that move outputs answer 04).
//! `cargo +nightly fuzz run modbus_path` (from the repository root).
#![no_main]

use core::cell::RefCell;

use embassy_futures::block_on;
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Instant};
use libfuzzer_sys::fuzz_target;
use remodaq_modbus::frame::{classify, Frame, MAX_ADU, MBAP_LEN};
use remodaq_modbus::server::answer_request;
use remodaq_shared::access::{AllowList, Network};
use remodaq_shared::modbus::{Access, RegisterMap, Table, MAX_PDU};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{Schema, SettingsStore};

type Flash = RamFlash<{ 64 * 1024 }, { 16 * 1024 }>;

/// The protocol crate's access rule of the module under test.
type AccessRule = fn(Table, u16) -> Access;

/// Whether the protocol crate says every address of the request's range allows its access.
fn range_allowed(rule: AccessRule, function: u8, start: u16, quantity: u16) -> bool {
    let (table, write) = match function {
        0x01 | 0x02 => (Table::Bits, false),
        0x03 | 0x04 => (Table::Registers, false),
        0x05 | 0x0F => (Table::Bits, true),
        _ => (Table::Registers, true),
    };
    u32::from(start) + u32::from(quantity) <= 0x1_0000
        && (0..quantity).all(|i| {
            let access = rule(table, start + i);
            if write {
                access.writable()
            } else {
                access.readable()
            }
        })
}

fn check(rule: AccessRule, request: &[u8], answer: &[u8]) {
    assert!(answer.len() >= MBAP_LEN + 2 && answer.len() <= MAX_ADU, "answer length {}", answer.len());
    let pdu = &answer[MBAP_LEN..];
    assert!(pdu.len() <= MAX_PDU);
    let length = usize::from(u16::from_be_bytes([answer[4], answer[5]]));
    assert_eq!(length, pdu.len() + 1, "MBAP length field");
    assert_eq!(&answer[..2], &request[..2], "transaction id echoed");
    assert_eq!(&answer[2..4], &[0, 0], "protocol id 0");
    assert_eq!(answer[6], request[6], "unit id echoed");
    let function = request.get(MBAP_LEN).copied().unwrap_or(0);
    if pdu[0] & 0x80 != 0 {
        assert_eq!(pdu[0], function | 0x80, "the exception echoes the function");
        assert!((1..=4).contains(&pdu[1]), "exception code {}", pdu[1]);
        assert_eq!(pdu.len(), 2, "an exception is two bytes");
        return;
    }
    assert_eq!(pdu[0], function, "the function is echoed");
    let req = &request[MBAP_LEN..];
    let start = u16::from_be_bytes([req[1], req[2]]);
    let quantity = u16::from_be_bytes([req[3], req[4]]);
    // An answered request only touched addresses the protocol crate maps for that access.
    let count = if matches!(function, 0x05 | 0x06) { 1 } else { quantity };
    assert!(range_allowed(rule, function, start, count), "answered outside the map: {req:02x?}");
    match function {
        0x01 | 0x02 => {
            assert_eq!(usize::from(pdu[1]), usize::from(quantity).div_ceil(8));
            assert_eq!(pdu.len(), 2 + usize::from(pdu[1]));
        }
        0x03 | 0x04 => {
            assert_eq!(usize::from(pdu[1]), 2 * usize::from(quantity));
            assert_eq!(pdu.len(), 2 + usize::from(pdu[1]));
        }
        0x05 | 0x06 | 0x0F | 0x10 => assert_eq!(pdu, &req[..5], "a write echoes start and quantity or value"),
        other => panic!("function {other:02x} answered without an exception"),
    }
}

fn serve<M: RegisterMap>(rule: AccessRule, map: &Mutex<NoopRawMutex, M>, from: [u8; 4], mut stream: &[u8]) {
    let mut out = [0u8; MAX_ADU];
    loop {
        match classify(stream) {
            Frame::Incomplete | Frame::Desync => return,
            Frame::Discard { len } => stream = &stream[len..],
            Frame::Request { header, len } => {
                let n = block_on(answer_request(map, from, header, &stream[MBAP_LEN..len], &mut out));
                check(rule, &stream[..len], &out[..n]);
                stream = &stream[len..];
            }
        }
    }
}

/// Scene bits of the second byte.
const FROM_SECOND: u8 = 1 << 0;
const RESTRICTED: u8 = 1 << 1;
const TRIPPED: u8 = 1 << 2;
const AUTO_CLEAR: u8 = 1 << 3;

/// The store, with `change` applied to the factory settings and committed.
fn store<S: Schema + Copy>(change: impl FnOnce(&mut S)) -> Mutex<CriticalSectionRawMutex, SettingsStore<Flash, S>> {
    let mut store =
        block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, S>::config(0..64 * 1024) }));
    let mut settings = S::defaults();
    change(&mut settings);
    if settings != S::defaults() {
        block_on(store.commit(settings)).expect("a RAM flash commits");
    }
    Mutex::new(store)
}

fuzz_target!(|data: &[u8]| {
    let Some((&[which, scene], stream)) = data.split_first_chunk::<2>() else { return };
    let from = if scene & FROM_SECOND != 0 { [127, 0, 0, 2] } else { [127, 0, 0, 1] };
    let allow = if scene & RESTRICTED != 0 {
        AllowList::of(&[Network::new([127, 0, 0, 2], 32).expect("a /32")]).expect("one network")
    } else {
        AllowList::EMPTY
    };
    if which & 1 == 0 {
        type Settings = remodaq_8318::settings::Settings;
        let store = store(|s: &mut Settings| s.allow = allow);
        let settings = *block_on(store.lock()).get();
        let map = Mutex::new(remodaq_8318::map::Map8318::new(&store, &settings));
        serve(remodaq_protocol::m8318::access, &map, from, stream);
    } else {
        type Settings = remodaq_8350::settings::Settings;
        let store = store(|s: &mut Settings| {
            s.allow = allow;
            if scene & TRIPPED != 0 {
                s.watchdog.timeout = 1;
                s.safe = 0b10_0101;
            }
            if scene & AUTO_CLEAR != 0 {
                s.watchdog.mode = remodaq_protocol::m8350::wd_mode::AUTO_CLEAR;
            }
        });
        let settings = *block_on(store.lock()).get();
        let io = remodaq_8350::io::IoCell::<NoopRawMutex>::new(RefCell::new(remodaq_8350::io::Io::new(
            remodaq_8350::di::SAMPLE_RATE_HZ,
            &settings,
        )));
        remodaq_8350::io::with(&io, |s| {
            // Some input activity, so flags and counters have something to show.
            s.di.process(&[0, 0xFFF, 0, 0xA5A, 0x5A5]);
            if scene & TRIPPED != 0 {
                s.request(false);
                s.poll_watchdog(Instant::now() + Duration::from_secs(3600));
                assert!(s.watchdog.tripped(), "an armed 0.1 s watchdog trips after an hour");
            }
        });
        let map = Mutex::new(remodaq_8350::map::Map8350::new(&store, &settings, &io));
        serve(remodaq_protocol::m8350::access, &map, from, stream);
    }
});
