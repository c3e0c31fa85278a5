//! Spec §1.2, §1.3, §2.1 and §2.4 on the real 8318 map, through Modbus PDUs: the expected
//! answers are the spec's exceptions and values, written here as literals.
//! - a write whose commit fails answers 04 and the old value stays in force (§1.2, §1.3);
//! - a write that covers unmapped registers answers 02 and changes nothing;
//! - an enable mask above 00FFh, and a CJC offset outside ±50.00 °C, answer 03.

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use futures_executor::block_on;
use remodaq_8318::map::Map8318;
use remodaq_8318::settings::Settings;
use remodaq_shared::modbus::{handle_pdu, MAX_PDU};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::SettingsStore;

type Flash = RamFlash<{ 4 * 1024 }, 1024>;
type Store = Mutex<CriticalSectionRawMutex, SettingsStore<Flash, Settings>>;

async fn store() -> Store {
    let store = SettingsStore::<Flash, Settings>::open(
        Flash::new(),
        const { SettingsStore::<Flash, Settings>::config(0..4096) },
    )
    .await;
    Mutex::new(store)
}

/// One request PDU, its answer.
async fn ask(map: &Mutex<NoopRawMutex, Map8318<'_, Flash>>, pdu: &[u8]) -> Vec<u8> {
    let mut resp = [0u8; MAX_PDU];
    let n = handle_pdu(map, [127, 0, 0, 1], pdu, &mut resp).await;
    resp[..n].to_vec()
}

/// Reads 40201 (input type), 40216 (CJC offset), 40221 (enable mask).
async fn persisted(map: &Mutex<NoopRawMutex, Map8318<'_, Flash>>) -> [Vec<u8>; 3] {
    [
        ask(map, &[0x03, 0x00, 0xC8, 0x00, 0x01]).await,
        ask(map, &[0x03, 0x00, 0xD7, 0x00, 0x01]).await,
        ask(map, &[0x03, 0x00, 0xDC, 0x00, 0x01]).await,
    ]
}

#[test]
fn a_failed_commit_answers_04_and_keeps_the_old_value() {
    block_on(async {
        let store = store().await;
        let settings = *store.lock().await.get();
        let map = Mutex::<NoopRawMutex, _>::new(Map8318::new(&store, &settings));
        // 40201 = 0Fh (type K): committed.
        assert_eq!(ask(&map, &[0x06, 0x00, 0xC8, 0x00, 0x0F]).await, [0x06, 0x00, 0xC8, 0x00, 0x0F]);
        // The flash fails every write and erase from now on.
        store.lock().await.flash_mut().set_budget(Some(0));
        assert_eq!(ask(&map, &[0x06, 0x00, 0xC8, 0x00, 0x0E]).await, [0x86, 0x04], "exception 04");
        assert_eq!(ask(&map, &[0x10, 0x00, 0xDC, 0x00, 0x01, 0x02, 0x00, 0x0F]).await, [0x90, 0x04]);
        assert_eq!(ask(&map, &[0x03, 0x00, 0xC8, 0x00, 0x01]).await, [0x03, 0x02, 0x00, 0x0F], "type K stays");
        assert_eq!(ask(&map, &[0x03, 0x00, 0xDC, 0x00, 0x01]).await, [0x03, 0x02, 0x00, 0xFF], "mask stays");
        assert_eq!(store.lock().await.get().input_type, 0x0F, "the store holds the old value too");
        // The flash works again: the same write is committed.
        store.lock().await.flash_mut().set_budget(None);
        assert_eq!(ask(&map, &[0x06, 0x00, 0xC8, 0x00, 0x0E]).await, [0x06, 0x00, 0xC8, 0x00, 0x0E]);
        assert_eq!(ask(&map, &[0x03, 0x00, 0xC8, 0x00, 0x01]).await, [0x03, 0x02, 0x00, 0x0E]);
    });
}

#[test]
fn range_checks_answer_03_and_change_nothing() {
    block_on(async {
        let store = store().await;
        let settings = *store.lock().await.get();
        let map = Mutex::<NoopRawMutex, _>::new(Map8318::new(&store, &settings));
        let before = persisted(&map).await;
        assert_eq!(before[2], [0x03, 0x02, 0x00, 0xFF], "§2.1: the enable mask defaults to 00FFh");
        // §2.1: the enable mask is 0000h..00FFh.
        assert_eq!(ask(&map, &[0x06, 0x00, 0xDC, 0x01, 0x00]).await, [0x86, 0x03]);
        assert_eq!(ask(&map, &[0x06, 0x00, 0xDC, 0xFF, 0xFF]).await, [0x86, 0x03]);
        assert_eq!(ask(&map, &[0x06, 0x00, 0xDC, 0x00, 0xFF]).await, [0x06, 0x00, 0xDC, 0x00, 0xFF], "00FFh is in");
        // §2.4: -50.00 .. +50.00 °C: 5000 = 1388h and -5000 = EC78h are in; 5001 = 1389h and
        // -5001 = EC77h are out.
        assert_eq!(ask(&map, &[0x06, 0x00, 0xD7, 0x13, 0x89]).await, [0x86, 0x03]);
        assert_eq!(ask(&map, &[0x06, 0x00, 0xD7, 0xEC, 0x77]).await, [0x86, 0x03]);
        assert_eq!(persisted(&map).await, before, "nothing changed");
        assert_eq!(ask(&map, &[0x06, 0x00, 0xD7, 0x13, 0x88]).await, [0x06, 0x00, 0xD7, 0x13, 0x88]);
        assert_eq!(ask(&map, &[0x06, 0x00, 0xD7, 0xEC, 0x78]).await, [0x06, 0x00, 0xD7, 0xEC, 0x78]);
    });
}

/// The 8318's writable registers are not adjacent: a code-16 write over 40216..40221 also
/// covers 40217-40220, not mapped for writing. Exception 02, and nothing changes, not even
/// the two valid values at its ends (the 8350's tests cover writes of adjacent settings).
#[test]
fn a_write_over_unmapped_registers_changes_nothing() {
    block_on(async {
        let store = store().await;
        let settings = *store.lock().await.get();
        let map = Mutex::<NoopRawMutex, _>::new(Map8318::new(&store, &settings));
        let before = persisted(&map).await;
        assert_eq!(
            ask(&map, &[0x10, 0x00, 0xD7, 0x00, 0x06, 0x0C, 0x00, 0x64, 0, 0, 0, 0, 0, 0, 0, 0, 0x00, 0x0F]).await,
            [0x90, 0x02],
        );
        assert_eq!(persisted(&map).await, before, "nothing changed");
    });
}
