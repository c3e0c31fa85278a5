//! A service's settings beside the module's in the one store (MQTT's, issue #40): a record of
//! their own under their own key, read back after a restart, untouched by the module's commits
//! and theirs untouched by the service's, back to the defaults after a factory reset, and a
//! damaged record never read as settings.
#[path = "common/mod.rs"]
mod common;

use common::S;
use futures_executor::block_on;
use remodaq_shared::password::Credential;
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{key, RecordReader, RecordWriter, Schema, SettingsStore};

const SIZE: usize = 4096;
type Flash = RamFlash<SIZE, 1024>;

async fn open(flash: Flash) -> SettingsStore<Flash, S> {
    SettingsStore::open(flash, const { SettingsStore::<Flash, S>::config(0..SIZE as u32) }).await
}

/// A service's settings: a name and a period; unreadable ones are marked so.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Service {
    name: heapless::String<16>,
    period: u32,
    unreadable: bool,
}

impl Schema for Service {
    const VERSION: u8 = 1;
    fn defaults() -> Self {
        Self { name: heapless::String::new(), period: 10, unreadable: false }
    }
    fn unreadable() -> Self {
        Self { unreadable: true, ..Self::defaults() }
    }
    fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put(1, self.name.as_bytes());
        w.put_u32(2, self.period);
    }
    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        let d = Self::defaults();
        Self {
            name: r
                .get(1)
                .and_then(|b| core::str::from_utf8(b).ok())
                .and_then(|t| heapless::String::try_from(t).ok())
                .unwrap_or(d.name),
            period: r.u32(2).unwrap_or(d.period),
            unreadable: false,
        }
    }
}

const OWN: Credential =
    Credential { salt: [0x5A; 16], iterations: 4096, stored_key: [0xC3; 32], server_key: [0x3C; 32] };

fn line_2() -> Service {
    Service { name: heapless::String::try_from("line-2").unwrap(), period: 500, unreadable: false }
}

#[test]
fn a_services_record_lives_beside_the_modules_settings() {
    block_on(async {
        let mut store = open(Flash::new()).await;
        assert_eq!(store.service_record::<Service>(key::MQTT).await, Service::defaults(), "none yet: its defaults");
        store.commit(S { password: OWN, ..S::defaults() }).await.expect("the module's settings");
        store.commit_service_record(key::MQTT, &line_2()).await.expect("the service's");
        // Each commit again, the other's record untouched, and both after a restart.
        for period in [600, 700] {
            store.commit(S { password: OWN, ..S::defaults() }).await.expect("the module's again");
            store.commit_service_record(key::MQTT, &Service { period, ..line_2() }).await.expect("again");
        }
        let mut store = open(store.into_flash()).await;
        assert_eq!(store.get().password, OWN);
        assert_eq!(store.service_record::<Service>(key::MQTT).await, Service { period: 700, ..line_2() });
        // The module's own key is not a service's.
        assert_eq!(store.service_record::<Service>(1).await, Service::unreadable());
        assert!(store.commit_service_record(1, &line_2()).await.is_err());
        assert_eq!(store.get().password, OWN, "the module's record untouched");
        // A factory reset: the service back to its defaults, the module's settings as the reset
        // commits them.
        store.reset_service_records().await.expect("reset");
        let mut store = open(store.into_flash()).await;
        assert_eq!(store.service_record::<Service>(key::MQTT).await, Service::defaults());
        assert_eq!(store.get().password, OWN);
    });
}

#[test]
fn a_damaged_record_is_never_read_as_settings() {
    block_on(async {
        let mut store = open(Flash::new()).await;
        store.commit_service_record(key::MQTT, &line_2()).await.expect("commit");
        let mut image = *store.into_flash().image();
        // A byte of the name flipped: the store's own check (the item's CRC) refuses the item,
        // which then reads as none: the service's defaults (MQTT's: off), never the damaged name.
        let at = image.windows(6).position(|w| w == b"line-2").expect("the record in the image");
        image[at] ^= 0x20;
        let mut store = open(Flash::from_image(&image)).await;
        assert_eq!(store.service_record::<Service>(key::MQTT).await, Service::defaults());
    });
}
