//! The settings store under power cuts (spec §1.3): cut the power at every word write and page
//! erase of a commit, restart, and check that the store loads the old or the new value, never
//! anything else, and keeps working.

use futures_executor::block_on;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{encode_record, RecordReader, RecordWriter, Schema, SettingsStore, StoreError};

const PAGE: usize = 1024;
const SIZE: usize = 4 * PAGE;
type Flash = RamFlash<SIZE, PAGE>;

#[derive(Clone, Debug, PartialEq)]
struct Settings {
    serial: u32,
    name: [u8; 24],
    mode: u16,
}

impl Schema for Settings {
    const VERSION: u8 = 2;
    fn defaults() -> Self {
        Self { serial: 0, name: *b"factory-default-settings", mode: 7 }
    }
    fn unreadable() -> Self {
        Self::defaults()
    }
    fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put_u32(1, self.serial);
        w.put(2, &self.name);
        w.put_u16(3, self.mode);
    }
    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        let d = Self::defaults();
        Self {
            serial: r.u32(1).unwrap_or(d.serial),
            name: r.array(2).unwrap_or(d.name),
            mode: r.u16(3).filter(|m| *m < 100).unwrap_or(d.mode),
        }
    }
}

/// Version 1 of the same settings: no `mode` field yet.
#[derive(Clone, PartialEq)]
struct SettingsV1 {
    serial: u32,
}

impl Schema for SettingsV1 {
    const VERSION: u8 = 1;
    fn defaults() -> Self {
        Self { serial: 0 }
    }
    fn unreadable() -> Self {
        Self::defaults()
    }
    fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put_u32(1, self.serial);
    }
    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        Self { serial: r.u32(1).unwrap_or(0) }
    }
}

fn value(serial: u32) -> Settings {
    let mut name = [b'.'; 24];
    name[..8].copy_from_slice(format!("{serial:08}").as_bytes());
    Settings { serial, name, mode: (serial % 100) as u16 }
}

async fn open(flash: Flash) -> SettingsStore<Flash, Settings> {
    SettingsStore::open(flash, const { SettingsStore::<Flash, Settings>::config(0..SIZE as u32) }).await
}

/// Restart: power back, the store opened afresh on the same flash content.
async fn restart(store: SettingsStore<Flash, Settings>) -> SettingsStore<Flash, Settings> {
    let mut flash = store.into_flash();
    flash.set_budget(None);
    open(flash).await
}

#[test]
fn blank_flash_gives_defaults_and_commits_survive_restart() {
    block_on(async {
        let mut store = open(Flash::new()).await;
        assert_eq!(store.get(), &Settings::defaults());
        store.commit(value(42)).await.unwrap();
        assert_eq!(store.get(), &value(42));
        let store = restart(store).await;
        assert_eq!(store.get(), &value(42));
    });
}

#[test]
fn garbage_flash_gives_defaults_and_keeps_working() {
    block_on(async {
        let mut image = vec![0u8; SIZE];
        for (i, b) in image.iter_mut().enumerate() {
            *b = (i * 7 + 3) as u8;
        }
        let mut store = open(Flash::from_image(&image)).await;
        assert_eq!(store.get(), &Settings::defaults());
        store.commit(value(5)).await.unwrap();
        let store = restart(store).await;
        assert_eq!(store.get(), &value(5));
    });
}

#[test]
fn record_of_an_older_version_loads_with_defaults_for_new_fields() {
    block_on(async {
        let cfg = const { SettingsStore::<Flash, SettingsV1>::config(0..SIZE as u32) };
        let mut old = SettingsStore::<Flash, SettingsV1>::open(Flash::new(), cfg).await;
        old.commit(SettingsV1 { serial: 1234 }).await.unwrap();
        let store = open(old.into_flash()).await;
        assert_eq!(store.get(), &Settings { serial: 1234, ..Settings::defaults() });
    });
}

#[test]
fn unknown_and_malformed_fields_are_skipped() {
    let mut buf = [0u8; 64];
    let n = encode_record(&value(9), &mut buf).unwrap();
    // Append an unknown tag, then a bad `mode` (out of range) that must fall back to the default.
    buf[n..n + 8].copy_from_slice(&[0x77, 2, 0xAA, 0xBB, 3, 2, 0xFF, 0xFF]);
    let decoded: Settings = remodaq_shared::settings::decode_record(&buf[..n + 8]).unwrap();
    assert_eq!(decoded, Settings { mode: 7, ..value(9) });
    let r = RecordReader::default_for_tests(&buf[2..4]);
    assert_eq!(r.get(1), None); // truncated field
}

/// True when a page that held data before reads all erased after.
fn erased_a_page(before: &[u8; SIZE], after: &[u8; SIZE]) -> bool {
    before
        .chunks(PAGE)
        .zip(after.chunks(PAGE))
        .any(|(b, a)| b.iter().any(|x| *x != 0xFF) && a.iter().all(|x| *x == 0xFF))
}

#[test]
fn power_cut_at_every_step_of_a_commit_loads_old_or_new() {
    // Several fill levels, so that cuts also land in page switches and erases.
    let mut cuts_checked = 0;
    let mut erases_cut = 0;
    for history in 0u32..=90 {
        let mut cut = 0usize;
        loop {
            let done = block_on(async {
                let mut store = open(Flash::new()).await;
                for serial in 1..=history {
                    store.commit(value(serial)).await.unwrap();
                }
                let old = store.get().clone();
                let new = value(1000 + history);
                let mut flash = store.into_flash();
                let image_before = *flash.image();
                flash.set_budget(Some(cut));
                let mut store = open(flash).await;
                let result = store.commit(new.clone()).await;
                let completed = result.is_ok();
                if !completed {
                    assert_eq!(result, Err(StoreError::Flash), "history {history} cut {cut}");
                    assert_eq!(store.get(), &old, "a failed commit leaves the old value in force");
                }
                let mut flash = store.into_flash();
                if !completed && erased_a_page(&image_before, flash.image()) {
                    erases_cut += 1;
                }
                flash.set_budget(None);
                let mut store = open(flash).await;
                let loaded = store.get().clone();
                if completed {
                    assert_eq!(loaded, new, "history {history}: acknowledged value lost");
                } else {
                    assert!(loaded == old || loaded == new, "history {history} cut {cut}: loaded {loaded:?}");
                }
                // And the store keeps working after the cut.
                store.commit(value(7777)).await.unwrap();
                let store = restart(store).await;
                assert_eq!(store.get(), &value(7777), "history {history} cut {cut}: store broken after cut");
                completed
            });
            cuts_checked += 1;
            if done {
                break;
            }
            cut += 1;
        }
    }
    eprintln!("power cuts exercised: {cuts_checked}, of which after a page erase: {erases_cut}");
    assert!(cuts_checked > 1000, "only {cuts_checked} cuts exercised");
    assert!(erases_cut > 0, "no cut landed after a page erase");
}

#[test]
fn power_cut_while_opening_after_a_cut() {
    // A cut during the repair that follows a cut: open, then a second cut at every step.
    for first in 0..12usize {
        for second in 0..12usize {
            block_on(async {
                let mut store = open(Flash::new()).await;
                for serial in 1..=38 {
                    store.commit(value(serial)).await.unwrap();
                }
                let mut flash = store.into_flash();
                flash.set_budget(Some(first));
                let mut store = open(flash).await;
                let _ = store.commit(value(500)).await;
                let mut flash = store.into_flash();
                flash.set_budget(Some(second));
                let mut store = open(flash).await;
                let _ = store.commit(value(501)).await;
                let store = restart(store).await;
                let serial = store.get().serial;
                assert!([38, 500, 501].contains(&serial), "cuts {first}/{second}: serial {serial}");
                assert_eq!(store.get(), &value(serial));
            });
        }
    }
}

/// Security review finding 1: restarting a module is open to anyone who holds its password,
/// the public factory one included, so a restart must not renew the flash commit budgets
/// (docs/security.md, "Flash wear": bursts of 20 authenticated commits and of 100 Modbus
/// writes' commits). Only a power-on, a brown-out or the reset pin (someone at the module)
/// starts them afresh.
#[test]
fn a_restart_renews_no_commit_budget() {
    use remodaq_shared::diagnostics::ResetCause;
    use remodaq_shared::settings::{Draw, Retained};
    let now = || embassy_time::Instant::now().as_millis();
    block_on(async {
        let mut store = open(Flash::new()).await;
        let t = now();
        assert_eq!((0..30).filter(|_| store.take(Draw::Admin, t)).count(), 20, "the administration's burst");
        assert_eq!((0..200).filter(|_| store.take(Draw::Write, t)).count(), 100, "the writes' burst");
        assert!(store.take(Draw::Counter, t), "an update's counters are never refused");
        let kept = store.retained(t);
        assert!(kept.admin_ms > 0 && kept.writes_ms > 0, "{kept:?}");
        let words = kept.to_words();
        assert_eq!(Retained::from_words(words), Some(kept));
        for cause in [ResetCause::Software, ResetCause::Watchdog, ResetCause::Unknown] {
            store.resume(cause, Retained::from_words(words));
            let t = now();
            assert!(!store.take(Draw::Admin, t) && !store.take(Draw::Write, t), "{cause:?} renewed a budget");
        }
        // What the board kept was lost or damaged: nothing in either budget until a refill.
        let mut damaged = words;
        damaged[2] ^= 1;
        assert_eq!(Retained::from_words(damaged), None);
        assert_eq!(Retained::from_words([0; 4]), None);
        store.resume(ResetCause::Software, None);
        let t = now();
        assert!(!store.take(Draw::Admin, t) && !store.take(Draw::Write, t), "a restart with nothing kept");
        // Someone at the module: a power-on starts both afresh, whatever was kept.
        for cause in [ResetCause::PowerOn, ResetCause::Pin, ResetCause::BrownOut] {
            store.resume(cause, Some(kept));
            let t = now();
            assert_eq!((0..30).filter(|_| store.take(Draw::Admin, t)).count(), 20, "{cause:?}");
        }
    });
}
