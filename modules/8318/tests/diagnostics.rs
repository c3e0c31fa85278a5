//! Extensions §1 through the real 8318 map (one test: the diagnostics are one static, and this
//! binary holds nothing else that touches them). Expected values are the spec's:
//! - reset causes: 0 power-on, 1 watchdog, 2 software, 3 reset pin, 4 brown-out, FFFFh
//!   unknown; status bit 3 set only after a watchdog reset;
//! - status bit 2: the last commit failed (set by a failed commit, cleared by a good one);
//! - the exception counter (40248) is 16 bits and wraps.

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use futures_executor::block_on;
use remodaq_8318::map::Map8318;
use remodaq_8318::settings::Settings;
use remodaq_modbus::frame::{Header, MAX_ADU};
use remodaq_modbus::server::answer_request;
use remodaq_shared::diagnostics::{ResetCause, DIAGNOSTICS};
use remodaq_shared::modbus::{handle_pdu, MAX_PDU};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::SettingsStore;

type Flash = RamFlash<{ 4 * 1024 }, 1024>;

#[test]
fn reset_causes_status_bits_and_the_exception_counter() {
    block_on(async {
        let store = SettingsStore::<Flash, Settings>::open(
            Flash::new(),
            const { SettingsStore::<Flash, Settings>::config(0..4096) },
        )
        .await;
        let settings = *store.get();
        let store = Mutex::<CriticalSectionRawMutex, _>::new(store);
        let map = Mutex::<NoopRawMutex, _>::new(Map8318::new(&store, &settings));
        let reg = async |addr: u8| {
            let mut resp = [0u8; MAX_PDU];
            let n = handle_pdu(&map, [127, 0, 0, 1], &[0x03, 0x00, addr, 0x00, 0x01], &mut resp).await;
            assert_eq!(n, 4, "{:02x?}", &resp[..n]);
            u16::from_be_bytes([resp[2], resp[3]])
        };
        // 40244 (00F3h): the reset cause; 40241 (00F0h) bit 3: this run follows a watchdog reset.
        for (cause, code, bit3) in [
            (ResetCause::PowerOn, 0x0000, false),
            (ResetCause::Watchdog, 0x0001, true),
            (ResetCause::Software, 0x0002, false),
            (ResetCause::Pin, 0x0003, false),
            (ResetCause::BrownOut, 0x0004, false),
            (ResetCause::Unknown, 0xFFFF, false),
        ] {
            DIAGNOSTICS.start(cause);
            assert_eq!(reg(0xF3).await, code, "{cause:?}");
            assert_eq!(reg(0xF0).await & 0x0008 != 0, bit3, "{cause:?}: status bit 3");
        }
        // Bit 2: a failed commit sets it, the next good one clears it.
        assert_eq!(reg(0xF0).await & 0x0004, 0);
        store.lock().await.flash_mut().set_budget(Some(0));
        let mut resp = [0u8; MAX_PDU];
        let n = handle_pdu(&map, [127, 0, 0, 1], &[0x06, 0x00, 0xC8, 0x00, 0x0E], &mut resp).await;
        assert_eq!(&resp[..n], [0x86, 0x04]);
        assert_eq!(reg(0xF0).await & 0x0004, 0x0004, "bit 2 after a failed commit");
        store.lock().await.flash_mut().set_budget(None);
        let n = handle_pdu(&map, [127, 0, 0, 1], &[0x06, 0x00, 0xC8, 0x00, 0x0E], &mut resp).await;
        assert_eq!(&resp[..n], [0x06, 0x00, 0xC8, 0x00, 0x0E]);
        assert_eq!(reg(0xF0).await & 0x0004, 0, "cleared by a good commit");
        // 40248 (00F7h): exception responses, 16 bits, wrapping. 65 536 more exceptions (a read
        // of the unmapped 40010) through the server's answer path leave it where it was; one
        // more adds one.
        let header = Header { transaction: 1, unit: 1 };
        let mut out = [0u8; MAX_ADU];
        let before = reg(0xF7).await;
        for _ in 0..65_536 {
            answer_request(&map, [127, 0, 0, 1], header, &[0x03, 0x00, 0x09, 0x00, 0x01], &mut out).await;
        }
        assert_eq!(&out[7..9], [0x83, 0x02], "an exception each time");
        assert_eq!(reg(0xF7).await, before, "wrapped after 65 536");
        answer_request(&map, [127, 0, 0, 1], header, &[0x03, 0x00, 0x09, 0x00, 0x01], &mut out).await;
        assert_eq!(reg(0xF7).await, before.wrapping_add(1));
    });
}
