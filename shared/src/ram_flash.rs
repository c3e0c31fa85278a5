//! A NOR flash in RAM with real NOR semantics (erase sets 0xFF, writes only clear bits,
//! word-aligned writes) and a power-cut switch: after a budget of word writes and page erases
//! the flash stops, as if power failed in the middle of an operation. Used by the settings
//! store's tests, by the host board (behind a file) and by boards whose settings region is RAM.

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// Why a [`RamFlash`] operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RamFlashError {
    /// Outside the flash.
    OutOfBounds,
    /// Offset or length not aligned to the word / page size.
    NotAligned,
    /// The power-cut budget ran out: the operation stopped part way.
    PowerCut,
}

impl NorFlashError for RamFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            RamFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            RamFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            RamFlashError::PowerCut => NorFlashErrorKind::Other,
        }
    }
}

/// `SIZE` bytes of NOR flash, `PAGE`-byte erase pages, 4-byte words (as the STM32F4).
pub struct RamFlash<const SIZE: usize, const PAGE: usize> {
    bytes: [u8; SIZE],
    /// Word writes and page erases left before the power is cut; `None`: unlimited.
    budget: Option<usize>,
    /// Word writes and page erases done so far.
    pub operations: usize,
}

impl<const SIZE: usize, const PAGE: usize> Default for RamFlash<SIZE, PAGE> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const SIZE: usize, const PAGE: usize> RamFlash<SIZE, PAGE> {
    /// A blank (erased) flash.
    pub const fn new() -> Self {
        Self { bytes: [0xFF; SIZE], budget: None, operations: 0 }
    }

    /// A flash holding `bytes` (e.g. loaded from an image file); missing bytes read erased.
    pub fn from_image(image: &[u8]) -> Self {
        let mut flash = Self::new();
        let n = image.len().min(SIZE);
        flash.bytes[..n].copy_from_slice(&image[..n]);
        flash
    }

    /// The whole content.
    pub fn image(&self) -> &[u8; SIZE] {
        &self.bytes
    }

    /// Cut the power after `ops` more word writes / page erases (`None`: never).
    pub fn set_budget(&mut self, ops: Option<usize>) {
        self.budget = ops;
    }

    /// True once the budget is spent.
    pub fn power_cut(&self) -> bool {
        self.budget == Some(0)
    }

    fn spend(&mut self) -> Result<(), RamFlashError> {
        match self.budget.as_mut() {
            Some(0) => Err(RamFlashError::PowerCut),
            Some(n) => {
                *n -= 1;
                self.operations += 1;
                Ok(())
            }
            None => {
                self.operations += 1;
                Ok(())
            }
        }
    }

    fn range(offset: u32, len: usize) -> Result<core::ops::Range<usize>, RamFlashError> {
        let start = offset as usize;
        let end = start.checked_add(len).ok_or(RamFlashError::OutOfBounds)?;
        if end > SIZE {
            return Err(RamFlashError::OutOfBounds);
        }
        Ok(start..end)
    }

    /// Blocking erase of `from..to` (page aligned).
    pub fn erase_now(&mut self, from: u32, to: u32) -> Result<(), RamFlashError> {
        let range = Self::range(from, to.saturating_sub(from) as usize)?;
        if !range.start.is_multiple_of(PAGE) || !range.end.is_multiple_of(PAGE) {
            return Err(RamFlashError::NotAligned);
        }
        for page in range.step_by(PAGE) {
            self.spend()?;
            self.bytes[page..page + PAGE].fill(0xFF);
        }
        Ok(())
    }

    /// Blocking write of `data` at `offset` (word aligned); NOR: bits only go from 1 to 0.
    pub fn write_now(&mut self, offset: u32, data: &[u8]) -> Result<(), RamFlashError> {
        let range = Self::range(offset, data.len())?;
        if !range.start.is_multiple_of(4) || !data.len().is_multiple_of(4) {
            return Err(RamFlashError::NotAligned);
        }
        for (i, word) in data.chunks_exact(4).enumerate() {
            self.spend()?;
            let at = range.start + 4 * i;
            for (dst, src) in self.bytes[at..at + 4].iter_mut().zip(word) {
                *dst &= *src;
            }
        }
        Ok(())
    }
}

impl<const SIZE: usize, const PAGE: usize> ErrorType for RamFlash<SIZE, PAGE> {
    type Error = RamFlashError;
}

impl<const SIZE: usize, const PAGE: usize> ReadNorFlash for RamFlash<SIZE, PAGE> {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        embedded_storage::nor_flash::ReadNorFlash::read(self, offset, bytes)
    }

    fn capacity(&self) -> usize {
        SIZE
    }
}

impl<const SIZE: usize, const PAGE: usize> NorFlash for RamFlash<SIZE, PAGE> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = PAGE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.erase_now(from, to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.write_now(offset, bytes)
    }
}

/// The blocking NOR traits as well (what a bootloader uses).
impl<const SIZE: usize, const PAGE: usize> embedded_storage::nor_flash::ReadNorFlash for RamFlash<SIZE, PAGE> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let range = Self::range(offset, bytes.len())?;
        bytes.copy_from_slice(&self.bytes[range]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        SIZE
    }
}

impl<const SIZE: usize, const PAGE: usize> embedded_storage::nor_flash::NorFlash for RamFlash<SIZE, PAGE> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = PAGE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.erase_now(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.write_now(offset, bytes)
    }
}
