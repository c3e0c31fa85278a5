//! Sector erases at x32 parallelism (stm32 review R3).
//!
//! embassy-stm32 0.6 erases with whatever PSIZE FLASH_CR holds (`flash/f4.rs`, `erase_sector`
//! only `modify`s SER, SNB and the interrupt enables), and its `disable_write` after every
//! program leaves PSIZE at 0: x8. RM0090 §3.6.2 ("Program/erase parallelism", Table 9): x32 is
//! allowed from 2.7 V to 3.6 V; the Nucleo-F429ZI and the RemoDAQ boards run the MCU at 3.3 V.
//! DS9405 ("Flash memory programming"): tERASE16KB at most 500 ms at x32 (800 ms at x8),
//! tERASE128KB 2 s (4 s at x8). [`X32`] sets PSIZE to x32 just before each erase.
//!
//! Every partition of the board is a [`Serialized`](remodaq_shared::flash::Serialized) over an
//! `X32` region: the controller's lock is held from here to the end of the erase, so no program
//! (which would leave PSIZE at x8 again) comes between. Were one to come between, the erase
//! would run at x8: slower, never wrong.

use embassy_stm32::pac;
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

/// A flash region whose erases run at x32 parallelism.
pub struct X32<F>(pub F);

impl<F: ErrorType> ErrorType for X32<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for X32<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes).await
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash> NorFlash for X32<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        parallelism_x32();
        let erased = self.0.erase(from, to).await;
        // embassy locks FLASH_CR again after an erase; and after one that failed before it
        // unlocked anything, this locks what `parallelism_x32` unlocked.
        pac::FLASH.cr().modify(|w| w.set_lock(true));
        erased
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write(offset, bytes).await
    }
}

/// FLASH_CR's PSIZE to x32 (RM0090 §3.9.7, FLASH_CR bits 9:8 = 0b10). FLASH_CR can be written
/// only once unlocked (§3.5.1: KEY1 0x4567_0123 then KEY2 0xCDEF_89AB into FLASH_KEYR); embassy's
/// erase finds it unlocked and goes on, and locks it at its end.
fn parallelism_x32() {
    if pac::FLASH.cr().read().lock() {
        pac::FLASH.keyr().write_value(0x4567_0123);
        pac::FLASH.keyr().write_value(0xCDEF_89AB);
    }
    pac::FLASH.cr().modify(|w| w.set_psize(pac::flash::vals::Psize::PSIZE32));
}
