//! The settings "flash" of the QEMU board: the 64 KiB region after the code (`SETTINGS` in this
//! board's memory.x), RAM in QEMU, driven with NOR semantics (erase to 0xFF, writes only clear
//! bits) so the settings store runs its real write path.

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// Size of the region.
pub const SIZE: usize = 64 * 1024;
/// Erase page (as the STM32's 16 KiB sectors).
pub const PAGE: usize = 16 * 1024;

unsafe extern "C" {
    static mut __settings_start: u8;
}

/// A flash access outside the region or misaligned.
#[derive(Debug, defmt::Format)]
pub struct FlashError;

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        NorFlashErrorKind::OutOfBounds
    }
}

/// The settings region, owned once.
pub struct SettingsFlash {
    base: *mut u8,
}

impl SettingsFlash {
    pub(crate) fn take() -> Self {
        // Only the address of the linker-defined region is taken; `init` runs once, so this is
        // the region's only owner.
        Self { base: core::ptr::addr_of_mut!(__settings_start) }
    }

    fn check(offset: u32, len: usize, align: usize) -> Result<usize, FlashError> {
        let start = offset as usize;
        match start.checked_add(len) {
            Some(end) if end <= SIZE && start.is_multiple_of(align) && len.is_multiple_of(align) => Ok(start),
            _ => Err(FlashError),
        }
    }
}

impl ErrorType for SettingsFlash {
    type Error = FlashError;
}

impl ReadNorFlash for SettingsFlash {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let start = Self::check(offset, bytes.len(), 1)?;
        for (i, b) in bytes.iter_mut().enumerate() {
            // SAFETY: inside the region (checked), which this value owns.
            *b = unsafe { core::ptr::read_volatile(self.base.add(start + i)) };
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        SIZE
    }
}

impl NorFlash for SettingsFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = PAGE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let start = Self::check(from, to.saturating_sub(from) as usize, PAGE)?;
        for i in start..to as usize {
            // SAFETY: inside the region (checked), which this value owns.
            unsafe { core::ptr::write_volatile(self.base.add(i), 0xFF) };
        }
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let start = Self::check(offset, bytes.len(), 4)?;
        for (i, b) in bytes.iter().enumerate() {
            // SAFETY: inside the region (checked), which this value owns. NOR: bits only clear.
            unsafe {
                let p = self.base.add(start + i);
                core::ptr::write_volatile(p, core::ptr::read_volatile(p) & b);
            }
        }
        Ok(())
    }
}
