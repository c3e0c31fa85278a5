//! The settings store against a model, with power cuts (in the style of sequential-storage's
//! own fuzz target): the input is a list of operations on a small RAM NOR flash (4 pages of
//! 1 KiB). A commit may be cut after any number of flash operations, then the power comes back
//! and the store reopens. The model: a completed commit is what the store holds and what a
//! restart loads; after a cut the store loads the old or the new value, never anything else,
//! and goes on working.
//! `cargo +nightly fuzz run settings_store` (from the repository root).
#![no_main]

use embassy_futures::block_on;
use libfuzzer_sys::fuzz_target;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema, SettingsStore};

const PAGE: usize = 1024;
const SIZE: usize = 4 * PAGE;
type Flash = RamFlash<SIZE, PAGE>;

#[derive(Clone, Copy, Debug, PartialEq)]
struct Settings {
    serial: u32,
    mode: u16,
    blob: [u8; 20],
}

impl Schema for Settings {
    const VERSION: u8 = 1;
    fn defaults() -> Self {
        Self { serial: 0, mode: 7, blob: [0x5A; 20] }
    }
    fn unreadable() -> Self {
        Self::defaults()
    }
    fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put_u32(1, self.serial);
        w.put_u16(2, self.mode);
        w.put(3, &self.blob);
    }
    fn decode(_: u8, r: &RecordReader<'_>) -> Self {
        let d = Self::defaults();
        Self {
            serial: r.u32(1).unwrap_or(d.serial),
            mode: r.u16(2).unwrap_or(d.mode),
            blob: r.array(3).unwrap_or(d.blob),
        }
    }
}

/// Power on: the store opened on the flash as it is.
fn open(mut flash: Flash) -> SettingsStore<Flash, Settings> {
    flash.set_budget(None);
    block_on(SettingsStore::open(flash, const { SettingsStore::<Flash, Settings>::config(0..SIZE as u32) }))
}

fuzz_target!(|data: &[u8]| {
    let mut store = open(Flash::new());
    let mut model = Settings::defaults();
    assert_eq!(*store.get(), model);
    for op in data.chunks_exact(4) {
        let &[kind, a, b, c] = op else { break };
        let value = Settings {
            serial: u32::from_le_bytes([a, b, c, kind]),
            mode: u16::from(a) << 8 | u16::from(c),
            blob: [b; 20],
        };
        match kind % 4 {
            // A commit that completes, then a restart sometimes.
            0 | 1 => {
                assert!(block_on(store.commit(value)).is_ok(), "a commit on a healthy flash succeeds");
                model = value;
                assert_eq!(*store.get(), model);
                if kind % 4 == 1 {
                    store = open(store.into_flash());
                    assert_eq!(*store.get(), model, "a restart loads the last committed value");
                }
            }
            // A commit cut after `a % 64` flash operations, then power back.
            2 => {
                // Open cleanly first (an open may finish the repair of an earlier cut), then
                // cut during the commit only.
                let mut flash = open(store.into_flash()).into_flash();
                flash.set_budget(Some(usize::from(a % 64)));
                let mut cut = block_on(SettingsStore::open(
                    flash,
                    const { SettingsStore::<Flash, Settings>::config(0..SIZE as u32) },
                ));
                let completed = block_on(cut.commit(value)).is_ok();
                if !completed {
                    assert_eq!(*cut.get(), model, "a failed commit leaves the old value in force");
                }
                store = open(cut.into_flash());
                let loaded = *store.get();
                if completed {
                    assert_eq!(loaded, value, "an acknowledged value is kept");
                } else {
                    assert!(loaded == model || loaded == value, "after a cut: {loaded:?}");
                }
                model = loaded;
            }
            // A plain restart.
            _ => {
                store = open(store.into_flash());
                assert_eq!(*store.get(), model, "a restart loads the last committed value");
            }
        }
    }
});
