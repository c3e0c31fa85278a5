//! A region of memory driven as NOR flash (erase sets 0xFF, writes only clear bits, 4-byte
//! words), with `ERASE`-byte pages: what the QEMU board uses as flash, since QEMU's MPS2 code
//! memory is plain writable RAM. Blocking (the bootloader) and async (the application) traits.
#![no_std]

use embedded_storage::nor_flash::{ErrorType, NorFlashError, NorFlashErrorKind};

/// An access outside the region or not aligned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegionError;

impl NorFlashError for RegionError {
    fn kind(&self) -> NorFlashErrorKind {
        NorFlashErrorKind::OutOfBounds
    }
}

/// `size` bytes of memory at `base` as NOR flash with `ERASE`-byte pages.
pub struct RamNor<const ERASE: usize> {
    base: *mut u8,
    size: usize,
}

// SAFETY: the region is owned by this value alone (the contract of `new`); moving it to another
// context moves that ownership.
unsafe impl<const ERASE: usize> Send for RamNor<ERASE> {}

impl<const ERASE: usize> RamNor<ERASE> {
    /// The region `base..base + size`.
    ///
    /// # Safety
    /// The region must be valid, writable memory owned by the returned value alone for as long
    /// as it lives (no other code reads or writes it meanwhile).
    pub const unsafe fn new(base: *mut u8, size: usize) -> Self {
        Self { base, size }
    }

    fn check(&self, offset: u32, len: usize, align: usize) -> Result<usize, RegionError> {
        let start = offset as usize;
        match start.checked_add(len) {
            Some(end) if end <= self.size && start.is_multiple_of(align) && len.is_multiple_of(align) => Ok(start),
            _ => Err(RegionError),
        }
    }

    fn read_now(&self, offset: u32, bytes: &mut [u8]) -> Result<(), RegionError> {
        let start = self.check(offset, bytes.len(), 1)?;
        for (i, b) in bytes.iter_mut().enumerate() {
            // SAFETY: inside the region (checked), which this value owns.
            *b = unsafe { core::ptr::read_volatile(self.base.add(start + i)) };
        }
        Ok(())
    }

    fn erase_now(&mut self, from: u32, to: u32) -> Result<(), RegionError> {
        let start = self.check(from, to.saturating_sub(from) as usize, ERASE)?;
        for i in start..to as usize {
            // SAFETY: inside the region (checked), which this value owns.
            unsafe { core::ptr::write_volatile(self.base.add(i), 0xFF) };
        }
        Ok(())
    }

    fn write_now(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RegionError> {
        let start = self.check(offset, bytes.len(), 4)?;
        for (i, b) in bytes.iter().enumerate() {
            // SAFETY: inside the region (checked), which this value owns. NOR: bits only clear.
            unsafe {
                let p = self.base.add(start + i);
                core::ptr::write_volatile(p, core::ptr::read_volatile(p) & b);
            }
        }
        Ok(())
    }

    /// Erases the whole region (every byte 0xFF).
    pub fn erase_all(&mut self) {
        for i in 0..self.size {
            // SAFETY: every byte is inside the region, which this value owns.
            unsafe { core::ptr::write_volatile(self.base.add(i), 0xFF) };
        }
    }

    /// Whether the region reads all zeros: memory never written since QEMU started (its
    /// power-on), as opposed to erased NOR flash (0xFF).
    pub fn untouched(&self) -> bool {
        // SAFETY: every byte is inside the region, which this value owns.
        (0..self.size).all(|i| unsafe { core::ptr::read_volatile(self.base.add(i)) } == 0)
    }
}

impl<const ERASE: usize> ErrorType for RamNor<ERASE> {
    type Error = RegionError;
}

impl<const ERASE: usize> embedded_storage::nor_flash::ReadNorFlash for RamNor<ERASE> {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RegionError> {
        self.read_now(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.size
    }
}

impl<const ERASE: usize> embedded_storage::nor_flash::NorFlash for RamNor<ERASE> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = ERASE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), RegionError> {
        self.erase_now(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RegionError> {
        self.write_now(offset, bytes)
    }
}

impl<const ERASE: usize> embedded_storage_async::nor_flash::ReadNorFlash for RamNor<ERASE> {
    const READ_SIZE: usize = 1;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RegionError> {
        self.read_now(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.size
    }
}

impl<const ERASE: usize> embedded_storage_async::nor_flash::NorFlash for RamNor<ERASE> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = ERASE;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), RegionError> {
        self.erase_now(from, to)
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RegionError> {
        self.write_now(offset, bytes)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};

    use super::*;

    #[test]
    fn nor_semantics_and_bounds() {
        let mut memory = std::vec![0u8; 64];
        // SAFETY: the vector outlives the region and nothing else touches it meanwhile.
        let mut nor = unsafe { RamNor::<16>::new(memory.as_mut_ptr(), 64) };
        assert!(nor.untouched());
        nor.erase(16, 32).unwrap();
        assert!(!nor.untouched());
        nor.write(16, &[0xF0, 0x0F, 0xAA, 0x55]).unwrap();
        nor.write(16, &[0x3C, 0xFF, 0xFF, 0xFF]).unwrap();
        let mut back = [0u8; 4];
        nor.read(16, &mut back).unwrap();
        assert_eq!(back, [0x30, 0x0F, 0xAA, 0x55], "writes only clear bits");
        assert_eq!(nor.erase(8, 24), Err(RegionError), "not page aligned");
        assert_eq!(nor.write(62, &[0; 4]), Err(RegionError), "past the end");
        assert_eq!(nor.write(17, &[0; 4]), Err(RegionError), "not word aligned");
        assert_eq!(nor.capacity(), 64);
    }
}
