//! The 8350 register map through the PDU engine: the manual's example frames (8350 §2.2-2.7)
//! byte-exact, and the bit and register rules of spec §3.1-3.2.

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::mutex::Mutex;
use futures_executor::block_on;
use remodaq_8350::io::{self, Io, IoCell};
use remodaq_8350::map::Map8350;
use remodaq_8350::settings::Settings;
use remodaq_shared::access::{AllowList, Network};
use remodaq_shared::modbus::{handle_pdu, MAX_PDU};
use remodaq_shared::module::Store;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{Schema, SettingsStore};

type Flash = RamFlash<{ 4 * 1024 }, 1024>;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

fn show(b: &[u8]) -> String {
    b.iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(" ")
}

struct Module {
    io: &'static IoCell<NoopRawMutex>,
    store: &'static Store<Flash, Settings>,
    map: Mutex<NoopRawMutex, Map8350<'static, Flash, NoopRawMutex>>,
}

impl Module {
    fn new() -> Self {
        Self::with_flash(Flash::new())
    }

    /// A module starting on `flash`: its I/O state built from the settings it loads, as the
    /// firmware builds it (`M8350::state`).
    fn with_flash(flash: Flash) -> Self {
        let store = block_on(SettingsStore::open(flash, const { SettingsStore::<Flash, Settings>::config(0..4096) }));
        let settings = *store.get();
        let io: &'static IoCell<NoopRawMutex> =
            Box::leak(Box::new(IoCell::new(core::cell::RefCell::new(Io::new(1000, &settings)))));
        let store: &'static Store<Flash, Settings> = Box::leak(Box::new(Mutex::new(store)));
        Self { io, store, map: Mutex::new(Map8350::new(store, &settings, io)) }
    }

    /// Sends an RTU-style example (station, then PDU) and answers the same way.
    fn ask(&mut self, frame: &str) -> String {
        self.ask_from([127, 0, 0, 1], frame)
    }

    /// [`Module::ask`] from the client at `from`.
    fn ask_from(&mut self, from: [u8; 4], frame: &str) -> String {
        let frame = hex(frame);
        let mut resp = [0u8; MAX_PDU];
        let n = block_on(handle_pdu(&self.map, from, &frame[1..], &mut resp));
        format!("{:02X} {}", frame[0], show(&resp[..n]))
    }

    fn inputs(&self, samples: &[u16]) {
        io::with(self.io, |s| s.di.process(samples));
    }
}

#[test]
fn manual_2_2_read_di0_to_di7() {
    let mut m = Module::new();
    m.inputs(&[0x0FFF]);
    assert_eq!(m.ask("01 01 00 00 00 08"), "01 01 01 FF");
    m.inputs(&[0x0A5]);
    assert_eq!(m.ask("01 02 00 00 00 0C"), "01 02 02 A5 00");
}

/// Runs inside the DI block start anywhere (spec §3.1: bit n of the answer is the n-th
/// address asked); a run past DI11 reaches an unmapped address (exception 02).
#[test]
fn di_runs_from_any_address() {
    let mut m = Module::new();
    // DI0, DI2, DI5, DI7 and DI11 high.
    m.inputs(&[0x8A5]);
    // DI2..DI6: DI2 and DI5 high.
    assert_eq!(m.ask("01 02 00 02 00 05"), "01 02 01 09");
    // DI5..DI11: DI5, DI7 and DI11 high.
    assert_eq!(m.ask("01 01 00 05 00 07"), "01 01 01 45");
    assert_eq!(m.ask("01 02 00 0A 00 03"), "01 82 02");
    assert_eq!(m.ask("01 02 00 0F 00 02"), "01 82 02", "an unmapped address before DO0");
}

#[test]
fn manual_2_4_start_counter_of_di0() {
    let mut m = Module::new();
    assert_eq!(m.ask("01 05 00 20 00 00"), "01 05 00 20 00 00");
    assert_eq!(m.ask("01 01 00 20 00 01"), "01 01 01 00");
    assert_eq!(m.ask("01 05 00 20 FF 00"), "01 05 00 20 FF 00");
    assert_eq!(m.ask("01 01 00 20 00 01"), "01 01 01 01");
}

#[test]
fn manual_2_5_set_do0_do1() {
    let mut m = Module::new();
    assert_eq!(m.ask("01 0F 00 10 00 02 01 03"), "01 0F 00 10 00 02");
    assert_eq!(m.ask("01 01 00 10 00 06"), "01 01 01 03");
    assert_eq!(m.ask("01 03 01 2E 00 01"), "01 03 02 00 03");
    assert_eq!(io::with(m.io, |s| s.pulse.tick()), 0b11);
}

#[test]
fn manual_2_6_all_do_register() {
    let mut m = Module::new();
    assert_eq!(m.ask("01 06 01 2E 00 03"), "01 06 01 2E 00 03");
    assert_eq!(m.ask("01 01 00 10 00 06"), "01 01 01 03");
    assert_eq!(m.ask("01 06 01 2E 00 40"), "01 86 03", "bits 6-15 must be 0");
    assert_eq!(m.ask("01 06 01 2C 00 01"), "01 86 02", "all DI is read only (decision)");
}

#[test]
fn manual_2_7_set_di_modes_with_the_errata_answer() {
    let mut m = Module::new();
    // The manual prints the answer as 01 01 01 00 00 06; the spec's errata: 01 10 01 00 00 06.
    assert_eq!(m.ask("01 10 01 00 00 06 0C 00 04 00 04 00 04 00 04 00 01 00 00"), "01 10 01 00 00 06");
    assert_eq!(m.ask("01 03 01 00 00 06"), "01 03 0C 00 04 00 04 00 04 00 04 00 01 00 00");
}

#[test]
fn counters_are_32_bit_low_word_first() {
    let mut m = Module::new();
    m.ask("01 06 01 05 00 01"); // DI5 counter mode
    io::with(m.io, |s| s.di.preset_counter(5, 0x1234_5678));
    assert_eq!(m.ask("01 04 00 0A 00 02"), "01 04 04 56 78 12 34");
}

#[test]
fn flags_clear_on_read_and_on_writing_0() {
    let mut m = Module::new();
    m.ask("01 06 01 00 00 02"); // DI0 low-to-high latch
    m.inputs(&[0, 1]);
    assert_eq!(m.ask("01 01 00 23 00 01"), "01 01 01 01");
    assert_eq!(m.ask("01 01 00 23 00 01"), "01 01 01 00", "cleared by the read");
    m.inputs(&[0, 1]);
    assert_eq!(m.ask("01 05 00 23 00 00"), "01 05 00 23 00 00");
    assert_eq!(m.ask("01 01 00 23 00 01"), "01 01 01 00", "cleared by writing 0");
    // The clear bit reads 0; writing 1 to it clears the counter.
    m.ask("01 06 01 00 00 01");
    m.inputs(&[0, 1, 0, 1]);
    assert_eq!(m.ask("01 03 00 00 00 02"), "01 03 04 00 02 00 00");
    assert_eq!(m.ask("01 05 00 21 FF 00"), "01 05 00 21 FF 00");
    assert_eq!(m.ask("01 03 00 00 00 02"), "01 03 04 00 00 00 00");
    assert_eq!(
        m.ask("01 01 00 20 00 30"),
        "01 01 06 11 11 11 11 11 11",
        "per channel: run 1, clear 0, overflow 0, latch 0"
    );
}

/// Extensions §4, reads with a side effect (security review finding 2): while an allow-list is
/// set, a client outside it reads the latch and overflow flags and the "samples lost" bit as
/// they stand, without clearing them, so it cannot consume the master's events; the master's
/// own read clears them as before. Without a list, anyone's read clears (spec §3.1).
#[test]
fn only_a_client_that_may_write_clears_flags_by_reading_them() {
    let mut store =
        block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, Settings>::config(0..4096) }));
    let master = [10, 0, 0, 5];
    let outsider = [192, 168, 1, 7];
    let mut s = Settings::defaults();
    s.allow = AllowList::of(&[Network::new([10, 0, 0, 0], 8).unwrap()]).unwrap();
    block_on(store.commit(s)).unwrap();
    let mut m = Module::with_flash(store.into_flash());
    assert_eq!(m.ask_from(master, "01 06 01 00 00 02"), "01 06 01 00 00 02", "DI0 low-to-high latch");
    m.inputs(&[0, 1]);
    for _ in 0..3 {
        assert_eq!(m.ask_from(outsider, "01 01 00 23 00 01"), "01 01 01 01", "the outsider sees the latch");
    }
    assert_eq!(m.ask_from(master, "01 01 00 23 00 01"), "01 01 01 01", "the master's event is still there");
    assert_eq!(m.ask_from(master, "01 01 00 23 00 01"), "01 01 01 00", "the master's read cleared it");
    // The same with no list: the first reader clears, whoever it is.
    let mut open = Module::new();
    open.ask("01 06 01 00 00 02");
    open.inputs(&[0, 1]);
    assert_eq!(open.ask_from(outsider, "01 01 00 23 00 01"), "01 01 01 01");
    assert_eq!(open.ask_from(outsider, "01 01 00 23 00 01"), "01 01 01 00", "no list: cleared by any read");
}

#[test]
fn unmapped_and_invalid() {
    let mut m = Module::new();
    assert_eq!(m.ask("01 01 00 0C 00 01"), "01 81 02");
    assert_eq!(m.ask("01 01 00 16 00 01"), "01 81 02");
    assert_eq!(m.ask("01 05 00 00 FF 00"), "01 85 02", "DI states are read only");
    assert_eq!(m.ask("01 06 00 00 00 01"), "01 86 02", "counters are read only");
    assert_eq!(m.ask("01 06 00 D4 A2 00"), "01 86 02", "version: writes answer 02 (decision)");
    assert_eq!(m.ask("01 06 01 00 00 05"), "01 86 03", "DI mode 5");
    assert_eq!(m.ask("01 06 01 00 01 01"), "01 86 03", "high byte of a mode must be 0");
    assert_eq!(m.ask("01 06 01 10 00 02"), "01 86 03", "DO mode 2");
    assert_eq!(m.ask("01 10 00 18 00 02 04 00 00 00 00"), "01 90 03", "width 0");
    assert_eq!(m.ask("01 06 01 0C 00 00"), "01 86 02");
}

#[test]
fn pulse_settings_persist_and_extra_pulses_add() {
    let mut m = Module::new();
    // DO0: pulse mode, low 2, high 3 (0.1 ms), 4 pulses.
    assert_eq!(m.ask("01 06 01 10 00 01"), "01 06 01 10 00 01");
    assert_eq!(m.ask("01 10 00 18 00 02 04 00 02 00 00"), "01 10 00 18 00 02");
    assert_eq!(m.ask("01 10 00 24 00 02 04 00 03 00 00"), "01 10 00 24 00 02");
    assert_eq!(m.ask("01 10 00 30 00 02 04 00 04 00 00"), "01 10 00 30 00 02");
    assert_eq!(m.ask("01 05 00 10 FF 00"), "01 05 00 10 FF 00");
    let ticks: String = (0..5).map(|_| if io::with(m.io, |s| s.pulse.tick()) & 1 == 1 { '#' } else { '.' }).collect();
    assert_eq!(ticks, "###..");
    assert_eq!(m.ask("01 10 00 3C 00 02 04 00 02 00 00"), "01 10 00 3C 00 02");
    let ticks: String = (0..40).map(|_| if io::with(m.io, |s| s.pulse.tick()) & 1 == 1 { '#' } else { '.' }).collect();
    assert_eq!(ticks.matches("###").count(), 5, "3 left + 2 extra: {ticks}");
    assert_eq!(m.ask("01 01 00 10 00 01"), "01 01 01 00", "the train ended");
    // Restart on the same flash: modes and pulse settings are back, outputs off.
    let store = std::mem::replace(&mut m, Module::new()).store;
    let blank =
        block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, Settings>::config(0..4096) }));
    let flash = std::mem::replace(&mut *block_on(store.lock()), blank).into_flash();
    let mut m = Module::with_flash(flash);
    assert_eq!(m.ask("01 03 01 10 00 01"), "01 03 02 00 01");
    assert_eq!(m.ask("01 03 00 18 00 02"), "01 03 04 00 02 00 00");
    assert_eq!(m.ask("01 03 00 30 00 02"), "01 03 04 00 04 00 00");
    assert_eq!(m.ask("01 01 00 10 00 06"), "01 01 01 00");
}

/// DO0 in pulse mode with `count` pulses of high 3 / low 2 ticks, started.
fn started_train(m: &mut Module, count: u16) {
    assert_eq!(m.ask("01 06 01 10 00 01"), "01 06 01 10 00 01");
    m.ask("01 10 00 18 00 02 04 00 02 00 00");
    m.ask("01 10 00 24 00 02 04 00 03 00 00");
    m.ask(&format!("01 10 00 30 00 02 04 {:02X} {:02X} 00 00", count >> 8, count & 0xFF));
    assert_eq!(m.ask("01 05 00 10 FF 00"), "01 05 00 10 FF 00");
}

/// Pulses DO0 plays before its train ends (at most `limit`), ticking the engine.
fn pulses_left(m: &Module, limit: u32) -> u32 {
    let (mut pulses, mut last) = (0, 0);
    for _ in 0..limit * 5 + 10 {
        let level = io::with(m.io, |s| s.pulse.tick()) & 1;
        pulses += u32::from(level == 1 && last == 0);
        last = level;
    }
    pulses
}

#[test]
fn extra_pulses_are_added_once_per_request_that_writes_the_low_word() {
    // Spec §3.4. Each case: a train of 4 pulses, then the writes, then count what is played.
    // One code-16 write of both words (low 2, high 0): 4 + 2.
    let mut m = Module::new();
    started_train(&mut m, 4);
    assert_eq!(m.ask("01 10 00 3C 00 02 04 00 02 00 00"), "01 10 00 3C 00 02");
    assert_eq!(pulses_left(&m, 100), 6);
    // Two code-06 writes, high word first (0), then the low word (3): added once, 4 + 3.
    let mut m = Module::new();
    started_train(&mut m, 4);
    assert_eq!(m.ask("01 06 00 3D 00 00"), "01 06 00 3D 00 00");
    assert_eq!(m.ask("01 06 00 3C 00 03"), "01 06 00 3C 00 03");
    assert_eq!(pulses_left(&m, 100), 7);
    // Low word first (3), then the high word (0): the low word's request adds 3, the high
    // word's only stores: 4 + 3, not 4 + 3 + 3.
    let mut m = Module::new();
    started_train(&mut m, 4);
    assert_eq!(m.ask("01 06 00 3C 00 03"), "01 06 00 3C 00 03");
    assert_eq!(m.ask("01 06 00 3D 00 00"), "01 06 00 3D 00 00");
    assert_eq!(m.ask("01 03 00 3C 00 02"), "01 03 04 00 03 00 00", "reads back as written");
    assert_eq!(pulses_left(&m, 100), 7);
    // The high word alone adds nothing, even when it makes the value large.
    let mut m = Module::new();
    started_train(&mut m, 4);
    assert_eq!(m.ask("01 06 00 3D 00 01"), "01 06 00 3D 00 01");
    assert_eq!(pulses_left(&m, 100), 4);
    // A 32-bit value through one request: 65536 + 1 extra pulses.
    let mut m = Module::new();
    started_train(&mut m, 4);
    assert_eq!(m.ask("01 10 00 3C 00 02 04 00 01 00 01"), "01 10 00 3C 00 02");
    assert_eq!(pulses_left(&m, 70_000), 4 + 65_537);
}

#[test]
fn extra_pulses_while_continuous_or_stopped_only_store() {
    // Continuous (count 0): still continuous, never ends.
    let mut m = Module::new();
    started_train(&mut m, 0);
    assert_eq!(m.ask("01 10 00 3C 00 02 04 00 05 00 00"), "01 10 00 3C 00 02");
    // The window is 50 x 5 + 10 = 260 ticks: 52 pulses begin in it; the train runs on.
    assert_eq!(pulses_left(&m, 50), 52);
    assert_eq!(m.ask("01 01 00 10 00 01"), "01 01 01 01");
    // Stopped: nothing starts, and a later start plays its own count only.
    let mut m = Module::new();
    started_train(&mut m, 4);
    assert_eq!(m.ask("01 05 00 10 00 00"), "01 05 00 10 00 00");
    assert_eq!(m.ask("01 10 00 3C 00 02 04 00 05 00 00"), "01 10 00 3C 00 02");
    assert_eq!(pulses_left(&m, 20), 0);
    assert_eq!(m.ask("01 03 00 3C 00 02"), "01 03 04 00 05 00 00");
    assert_eq!(m.ask("01 05 00 10 FF 00"), "01 05 00 10 FF 00");
    assert_eq!(pulses_left(&m, 20), 4);
}

#[test]
fn overflow_at_2_pow_32_and_falling_latch_through_modbus() {
    let mut m = Module::new();
    // DI4 counter at FFFFFFFFh: one rising edge wraps it to 0 and sets its overflow flag
    // (0X 00035 + 4 x 4 = bit 32h), read with code 01 and again with code 02.
    assert_eq!(m.ask("01 06 01 04 00 01"), "01 06 01 04 00 01");
    io::with(m.io, |s| s.di.preset_counter(4, u32::MAX));
    m.inputs(&[0, 1 << 4]);
    assert_eq!(m.ask("01 04 00 08 00 02"), "01 04 04 00 00 00 00", "wrapped to 0");
    assert_eq!(m.ask("01 02 00 32 00 01"), "01 02 01 01", "overflow flag");
    assert_eq!(m.ask("01 01 00 32 00 01"), "01 01 01 00", "cleared by the read");
    // DI2 high-to-low latch (0X 00036 + 4 x 2 = bit 2Bh): a rise does not set it, a fall does.
    assert_eq!(m.ask("01 06 01 02 00 03"), "01 06 01 02 00 03");
    m.inputs(&[0, 1 << 2]);
    assert_eq!(m.ask("01 02 00 2B 00 01"), "01 02 01 00", "rising edge");
    m.inputs(&[0]);
    assert_eq!(m.ask("01 01 00 2B 00 01"), "01 01 01 01", "falling edge");
    assert_eq!(m.ask("01 02 00 2B 00 01"), "01 02 01 00", "cleared by the read");
}

/// Spec §1.2 and §1.3 on the real 8350 map: a write whose commit fails answers 04 and the old
/// values stay in force, in the map and in the store.
#[test]
fn a_failed_commit_answers_04_and_keeps_the_old_values() {
    let mut m = Module::new();
    assert_eq!(m.ask("01 06 01 00 00 01"), "01 06 01 00 00 01", "DI0: counter");
    let widths = m.ask("01 03 00 18 00 04");
    block_on(m.store.lock()).flash_mut().set_budget(Some(0));
    assert_eq!(m.ask("01 06 01 00 00 04"), "01 86 04");
    assert_eq!(m.ask("01 10 00 18 00 04 08 00 07 00 00 00 09 00 00"), "01 90 04", "two pulse widths");
    assert_eq!(m.ask("01 06 01 10 00 01"), "01 86 04", "a DO mode");
    assert_eq!(m.ask("01 03 01 00 00 01"), "01 03 02 00 01", "DI0 is still a counter");
    assert_eq!(m.ask("01 03 00 18 00 04"), widths, "the widths stay");
    assert_eq!(m.ask("01 03 01 10 00 01"), "01 03 02 00 00", "DO0 stays normal");
    assert_eq!(
        block_on(m.store.lock()).get().di_modes[0],
        remodaq_8350::di::DiMode::Counter,
        "the store holds the old value too"
    );
    block_on(m.store.lock()).flash_mut().set_budget(None);
    assert_eq!(m.ask("01 06 01 00 00 04"), "01 06 01 00 00 04", "the flash works again");
}

/// Spec §1.2: a multi-register or multi-bit write is validated whole; one bad value answers
/// 03 and none of it applies (Extensions §3: power-on levels use bits 0-5 only).
#[test]
fn a_multi_register_write_is_validated_whole() {
    let mut m = Module::new();
    // Twelve DI modes, the eleventh 9 (modes are 0-4).
    assert_eq!(
        m.ask("01 10 01 00 00 0C 18 00 01 00 02 00 03 00 04 00 01 00 02 00 03 00 04 00 01 00 02 00 09 00 01"),
        "01 90 03"
    );
    assert_eq!(m.ask("01 03 01 00 00 0C"), format!("01 03 18 {}", ["00"; 24].join(" ")), "all still normal");
    // DO0's low width 7, DO1's 0 (widths are at least 1).
    let widths = m.ask("01 03 00 18 00 04");
    assert_eq!(m.ask("01 10 00 18 00 04 08 00 07 00 00 00 00 00 00"), "01 90 03");
    assert_eq!(m.ask("01 03 00 18 00 04"), widths);
    // DO modes 0, 1, 2: the third is out of range.
    assert_eq!(m.ask("01 10 01 10 00 03 06 00 00 00 01 00 02"), "01 90 03");
    assert_eq!(m.ask("01 03 01 10 00 03"), "01 03 06 00 00 00 00 00 00");
    // Power-on levels with bits 6-15 set.
    let power_on = m.ask("01 03 01 34 00 01");
    assert_eq!(m.ask("01 06 01 34 00 40"), "01 86 03", "bit 6");
    assert_eq!(m.ask("01 06 01 34 FF C0"), "01 86 03", "bits 6-15");
    assert_eq!(m.ask("01 03 01 34 00 01"), power_on);
    assert_eq!(m.ask("01 06 01 34 00 3F"), "01 06 01 34 00 3F", "bits 0-5 are fine");
}

/// Extensions §3: while the host watchdog is tripped, a write of extra pulses (it would move
/// an output) answers 04 and adds nothing.
#[test]
fn extra_pulses_while_tripped_answer_04() {
    let mut m = Module::new();
    started_train(&mut m, 1000);
    assert_eq!(m.ask("01 06 01 30 00 05"), "01 06 01 30 00 05", "a 0.5 s watchdog, armed");
    let later = embassy_time::Instant::now() + embassy_time::Duration::from_secs(5);
    io::with(m.io, |s| s.poll_watchdog(later));
    assert_eq!(m.ask("01 03 01 33 00 01"), "01 03 02 00 01", "tripped");
    let extra = m.ask("01 03 00 3C 00 02");
    assert_eq!(m.ask("01 10 00 3C 00 02 04 00 0A 00 00"), "01 90 04");
    assert_eq!(m.ask("01 06 00 3C 00 0A"), "01 86 04");
    assert_eq!(m.ask("01 03 00 3C 00 02"), extra, "nothing stored");
    assert_eq!(m.ask("01 01 00 10 00 01"), "01 01 01 00", "the train stopped at the trip");
}

/// Spec §3.5: counters, run bits, flags and output states are not persisted; modes are. After
/// a restart on the same flash: counters 0, run bits 1 (the power-up decision of
/// docs/register-map-8350.md), the
/// latch flag clear, and the outputs at their power-on levels (extensions §3), not at the
/// levels written before.
#[test]
fn counters_run_bits_and_flags_are_not_persisted() {
    let mut m = Module::new();
    assert_eq!(m.ask("01 06 01 00 00 01"), "01 06 01 00 00 01", "DI0 counter (persisted)");
    assert_eq!(m.ask("01 06 01 02 00 02"), "01 06 01 02 00 02", "DI2 low-to-high latch (persisted)");
    assert_eq!(m.ask("01 06 01 34 00 02"), "01 06 01 34 00 02", "power-on levels: DO1 on (persisted)");
    assert_eq!(m.ask("01 01 00 20 00 01"), "01 01 01 01", "DI0's counter runs from the start");
    m.inputs(&[0, 1, 0, 1, 0, 1, 0b100]);
    assert_eq!(m.ask("01 03 00 00 00 02"), "01 03 04 00 03 00 00", "3 edges counted");
    assert_eq!(m.ask("01 01 00 2B 00 01"), "01 01 01 01", "DI2 latched (the read clears it)");
    m.inputs(&[0, 0b100]);
    assert_eq!(m.ask("01 05 00 20 00 00"), "01 05 00 20 00 00", "DI0's counter stopped");
    assert_eq!(m.ask("01 0F 00 10 00 06 01 01"), "01 0F 00 10 00 06", "outputs: DO0 only");
    let store = std::mem::replace(&mut m, Module::new()).store;
    let blank =
        block_on(SettingsStore::open(Flash::new(), const { SettingsStore::<Flash, Settings>::config(0..4096) }));
    let flash = std::mem::replace(&mut *block_on(store.lock()), blank).into_flash();
    let mut m = Module::with_flash(flash);
    assert_eq!(m.ask("01 03 01 00 00 03"), "01 03 06 00 01 00 00 00 02", "modes persisted");
    assert_eq!(m.ask("01 03 00 00 00 02"), "01 03 04 00 00 00 00", "the counter starts at 0");
    assert_eq!(m.ask("01 01 00 20 00 01"), "01 01 01 01", "the run bit is back to 1");
    assert_eq!(m.ask("01 01 00 2B 00 01"), "01 01 01 00", "the latch flag set before is gone");
    assert_eq!(m.ask("01 01 00 10 00 06"), "01 01 01 02", "outputs at their power-on levels");
}

/// Point `i` as MQTT publishes it: read, then its payload written.
fn read(m: &Module, i: usize, payload: &mut remodaq_mqtt::session::Payload) {
    use remodaq_mqtt::session::Module as _;
    let mut module = mqtt(m);
    block_on(module.read(i));
    module.payload(payload);
}

/// MQTT's module over this map (issue #40, docs/mqtt.md).
fn mqtt(m: &Module) -> remodaq_mqtt::points::MapModule<'_, NoopRawMutex, Map8350<'static, Flash, NoopRawMutex>> {
    remodaq_mqtt::points::MapModule {
        map: &m.map,
        model: 0x8350,
        firmware: 0xA100,
        mac: [0, 0x80, 0xE1, 0, 0, 1],
        uptime_s: || 0,
        time_ms: || None,
        options: remodaq_mqtt::points::Options { deadbands: [0; 8], on_change: true, broker: [127, 0, 0, 1] },
        last: Default::default(),
    }
}

/// Issue #40: every published value equals a Modbus read of the same point (spec §3.1: DI n's
/// state at bit n; §3.2: its counter at registers 2n, 2n+1, low word first).
#[test]
fn mqtt_publishes_what_a_modbus_read_gives() {
    use remodaq_mqtt::session::Payload;
    let mut m = Module::new();
    assert_eq!(m.ask("01 06 01 03 00 01"), "01 06 01 03 00 01", "DI3 a counter");
    m.inputs(&[0, 0b1000, 0, 0b1000, 0, 0b1001]);
    let mut payload = Payload::new();
    for n in 0..12u16 {
        read(&m, usize::from(n), &mut payload);
        let o = remodaq_shared::json::Object::parse(payload.as_bytes()).expect("a flat JSON object");
        let state = m.ask(&format!("01 02 00 {n:02X} 00 01"));
        let counter = m.ask(&format!("01 03 00 {:02X} 00 02", 2 * n));
        let c = hex(&counter);
        // Station, function, byte count, then the low word and the high word.
        let modbus_counter = (u32::from(c[3]) << 8 | u32::from(c[4])) | (u32::from(c[5]) << 8 | u32::from(c[6])) << 16;
        assert_eq!(o.bool("state"), Some(state.ends_with("01")), "DI{n} {payload}");
        assert_eq!(o.u32("counter"), Some(modbus_counter), "DI{n} {payload}");
    }
    read(&m, 3, &mut payload);
    assert!(payload.contains("\"counter\":3") && payload.contains("\"state\":true"), "{payload}");
    read(&m, 12 + 2, &mut payload);
    assert!(payload.starts_with("{\"state\":false,\"mode\":\"normal\""), "DO2: {payload}");
}

/// Issue #40: a command is the Modbus writes of a master, all checked before any is applied
/// (a refused command changes nothing), refused while the watchdog has tripped.
#[test]
fn mqtt_commands_are_all_or_nothing() {
    use remodaq_mqtt::command::Command;
    use remodaq_mqtt::session::Module as _;
    let mut m = Module::new();
    let before = m.ask("01 03 00 18 00 24");
    // A zero low width (spec §3.4: each width >= 1): refused, nothing written.
    let bad = Command::Pulse { low: 0, high: 5, count: 3 };
    assert_eq!(block_on(mqtt(&m).command(1, bad)), Err(()));
    assert_eq!(m.ask("01 03 00 18 00 24"), before, "no width or count written");
    assert_eq!(m.ask("01 03 01 11 00 01"), "01 03 02 00 00", "DO1 still normal");
    // A good one: widths, count, pulse mode, started.
    assert_eq!(block_on(mqtt(&m).command(1, Command::Pulse { low: 5, high: 20, count: 3 })), Ok(()));
    assert_eq!(m.ask("01 03 00 1A 00 02"), "01 03 04 00 05 00 00", "DO1 low width 0.5 ms");
    assert_eq!(m.ask("01 03 00 26 00 02"), "01 03 04 00 14 00 00", "DO1 high width 2 ms");
    assert_eq!(m.ask("01 03 00 32 00 02"), "01 03 04 00 03 00 00", "DO1 3 pulses");
    assert_eq!(m.ask("01 03 01 11 00 01"), "01 03 02 00 01", "DO1 in pulse mode");
    assert_eq!(m.ask("01 01 00 11 00 01"), "01 01 01 01", "DO1's train running");
    // A level: normal mode, DO4 on.
    assert_eq!(block_on(mqtt(&m).command(4, Command::Level(true))), Ok(()));
    assert_eq!(m.ask("01 01 00 14 00 01"), "01 01 01 01");
    // Tripped: a command that moves an output is refused (as a Modbus write: 04).
    assert_eq!(m.ask("01 06 01 30 00 05"), "01 06 01 30 00 05", "a 0.5 s watchdog, armed");
    let later = embassy_time::Instant::now() + embassy_time::Duration::from_secs(5);
    io::with(m.io, |s| s.poll_watchdog(later));
    assert_eq!(block_on(mqtt(&m).command(0, Command::Level(true))), Err(()));
    assert_eq!(m.ask("01 01 00 10 00 01"), "01 01 01 00", "DO0 stays off");
}
