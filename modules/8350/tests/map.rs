//! The 8350 register map through the PDU engine: the manual's example frames (8350 §2.2-2.7)
//! byte-exact, and the bit and register rules of spec §3.1-3.2.

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use futures_executor::block_on;
use remodaq_8350::io::{self, Io, IoCell};
use remodaq_8350::map::Map8350;
use remodaq_8350::settings::Settings;
use remodaq_shared::modbus::{handle_pdu, MAX_PDU};
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
    map: Map8350<'static, Flash, NoopRawMutex>,
}

impl Module {
    fn new() -> Self {
        Self::with_flash(Flash::new())
    }

    fn with_flash(flash: Flash) -> Self {
        let io: &'static IoCell<NoopRawMutex> =
            Box::leak(Box::new(IoCell::new(core::cell::RefCell::new(Io::new(1000, &Settings::defaults())))));
        let store = block_on(SettingsStore::open(flash, const { SettingsStore::<Flash, Settings>::config(0..4096) }));
        Self { io, map: Map8350::new(store, io) }
    }

    /// Sends an RTU-style example (station, then PDU) and answers the same way.
    fn ask(&mut self, frame: &str) -> String {
        let frame = hex(frame);
        let mut resp = [0u8; MAX_PDU];
        let n = block_on(handle_pdu(&mut self.map, &frame[1..], &mut resp));
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
    let flash = std::mem::replace(&mut m, Module::new()).map.into_store().into_flash();
    let mut m = Module::with_flash(flash);
    assert_eq!(m.ask("01 03 01 10 00 01"), "01 03 02 00 01");
    assert_eq!(m.ask("01 03 00 18 00 02"), "01 03 04 00 02 00 00");
    assert_eq!(m.ask("01 03 00 30 00 02"), "01 03 04 00 04 00 00");
    assert_eq!(m.ask("01 01 00 10 00 06"), "01 01 01 00");
}
