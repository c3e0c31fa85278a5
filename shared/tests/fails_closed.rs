//! Security review finding 9 (issue #38): a settings store that was written and can no longer
//! be read must not load the factory password, which anyone knows: the module loads the
//! factory defaults with its credential locked (docs/security.md, "Migration" and "Flash
//! wear"), serves Modbus, and refuses administration until a physical factory reset.
#[path = "common/mod.rs"]
mod common;

use common::S;
use futures_executor::block_on;
use remodaq_shared::password::{Credential, LOCKED};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{Schema, SettingsStore};

const SIZE: usize = 4096;
type Flash = RamFlash<SIZE, 1024>;

async fn open(flash: Flash) -> SettingsStore<Flash, S> {
    SettingsStore::open(flash, const { SettingsStore::<Flash, S>::config(0..SIZE as u32) }).await
}

/// A password of the administrator's own (its keys as the store keeps them).
const OWN: Credential =
    Credential { salt: [0x5A; 16], iterations: 4096, stored_key: [0xC3; 32], server_key: [0x3C; 32] };

/// The flash of a module that was claimed: a commit with the administrator's credential.
fn claimed() -> [u8; SIZE] {
    block_on(async {
        let mut store = open(Flash::new()).await;
        assert_eq!(store.get().password, Credential::FACTORY, "a blank store: the factory password");
        store.commit(S { password: OWN, ..S::defaults() }).await.expect("commit");
        let store = open(store.into_flash()).await;
        assert_eq!(store.get().password, OWN, "read back");
        *store.into_flash().image()
    })
}

/// Where the record's credential lies in the image (its StoredKey).
fn credential_at(image: &[u8]) -> usize {
    image.windows(32).position(|w| w == [0xC3; 32]).expect("the credential in the image")
}

#[test]
fn a_store_that_cannot_be_read_loads_locked_not_factory() {
    let image = claimed();
    let at = credential_at(&image);
    type Damage = Box<dyn Fn(&mut [u8; SIZE])>;
    let damages: [(&str, Damage); 3] = [
        ("a byte of the record flipped (its checksum fails)", Box::new(move |i| i[at] ^= 0x01)),
        ("the first page's first 64 bytes overwritten", Box::new(|i| i[..64].fill(0x00))),
        ("the whole store overwritten (sequential-storage: Corrupted)", Box::new(|i| i.fill(0x55))),
    ];
    for (what, damage) in damages {
        let mut damaged = image;
        damage(&mut damaged);
        let store = block_on(open(Flash::from_image(&damaged)));
        let loaded = *store.get();
        assert_eq!(loaded.password, LOCKED, "{what}: the factory password would hand the module to anyone");
        assert_eq!(loaded, S { password: LOCKED, ..S::defaults() }, "{what}: otherwise the factory defaults");
        // Still locked at the next start (a corrupted store is erased and written again
        // locked: a blank one would load the factory password).
        let store = block_on(open(store.into_flash()));
        assert_eq!(store.get().password, LOCKED, "{what}: after a restart");
        // The physical factory reset (the USER button: a commit of the factory defaults).
        let mut store = store;
        block_on(store.commit(S::defaults())).expect("factory reset");
        let store = block_on(open(store.into_flash()));
        assert_eq!(store.get().password, Credential::FACTORY, "{what}: after a factory reset");
    }
    // The control: a blank store is a new module, with the factory password.
    assert_eq!(block_on(open(Flash::new())).get().password, Credential::FACTORY);
}

/// Security review finding 11b: the physical factory reset brings every setting back to its
/// factory default (the factory password, the factory network) but not the update counters,
/// or anyone who claimed the module next could install any older signed image.
#[test]
fn a_factory_reset_keeps_the_update_counter() {
    let claimed = S {
        password: OWN,
        net: remodaq_shared::net::NetConfig { ip: [10, 1, 2, 3], ..remodaq_shared::net::NetConfig::FACTORY },
        update: remodaq_shared::settings::Counter { confirmed: 5, pending: 6 },
        ..S::defaults()
    };
    // The store's value, written and read back as a module's is.
    let claimed = block_on(async {
        let mut store = open(Flash::new()).await;
        store.commit(claimed).await.expect("commit");
        *open(store.into_flash()).await.get()
    });
    let reset = remodaq_shared::module::factory_reset(&claimed);
    assert_eq!(reset.password, Credential::FACTORY);
    assert_eq!(reset.net, remodaq_shared::net::NetConfig::FACTORY);
    assert_eq!(reset.update, remodaq_shared::settings::Counter { confirmed: 5, pending: 6 }, "the counter went back");
    assert_eq!(reset, S { update: claimed.update, ..S::defaults() });
}
