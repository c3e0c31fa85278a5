//! The settings flash of the simulated module: a NOR flash with the STM32 geometry (64 KiB in
//! 16 KiB sectors) backed by an image file. Every write and erase reaches the file (and the
//! disk, `sync_data`) before it returns, so a setting acknowledged over Modbus survives the
//! process being killed, exactly as on the module.

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::Path;

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use remodaq_shared::ram_flash::{RamFlash, RamFlashError};

/// Size of the settings region (as STM32F429 bank 2 sectors 12-15).
pub const SIZE: usize = 64 * 1024;
/// Erase sector size.
pub const SECTOR: usize = 16 * 1024;

/// A flash operation failed.
#[derive(Debug)]
pub enum FileFlashError {
    /// Bad address or alignment.
    Flash(RamFlashError),
    /// The image file could not be written.
    File,
}

impl NorFlashError for FileFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FileFlashError::Flash(e) => e.kind(),
            FileFlashError::File => NorFlashErrorKind::Other,
        }
    }
}

/// NOR flash mirrored to an image file.
pub struct FileFlash {
    flash: Box<RamFlash<SIZE, SECTOR>>,
    file: File,
    delay: std::time::Duration,
}

impl FileFlash {
    /// Opens (or creates, blank) the image at `path`.
    pub fn open(path: &Path) -> std::io::Result<Self> {
        let mut file = OpenOptions::new().read(true).write(true).create(true).truncate(false).open(path)?;
        let mut image = Vec::new();
        file.read_to_end(&mut image)?;
        let flash = Box::new(RamFlash::from_image(&image));
        let mut flash = Self { flash, file, delay: std::time::Duration::ZERO };
        if image.len() != SIZE {
            flash.file.set_len(SIZE as u64)?;
            flash.write_through(0, SIZE)?;
        }
        Ok(flash)
    }

    /// Writes bytes `from..to` of the image to the file and to the disk (portable: a seek and a
    /// write, as on every OS).
    fn write_through(&mut self, from: usize, to: usize) -> std::io::Result<()> {
        self.file.seek(SeekFrom::Start(from as u64))?;
        self.file.write_all(&self.flash.image()[from..to])?;
        self.file.sync_data()
    }

    /// Makes every later write and erase take `delay` longer (a slow flash, `--slow-flash`):
    /// the wait yields, as a flash driver waiting for its interrupt does.
    pub fn slow_down(&mut self, delay: std::time::Duration) {
        self.delay = delay;
    }

    async fn persist(&mut self, from: usize, to: usize) -> Result<(), FileFlashError> {
        if !self.delay.is_zero() {
            async_io::Timer::after(self.delay).await;
        }
        self.write_through(from, to).map_err(|_| FileFlashError::File)
    }
}

impl ErrorType for FileFlash {
    type Error = FileFlashError;
}

impl ReadNorFlash for FileFlash {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes).await.map_err(FileFlashError::Flash)
    }

    fn capacity(&self) -> usize {
        SIZE
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.flash.erase_now(from, to).map_err(FileFlashError::Flash)?;
        self.persist(from as usize, to as usize).await
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.flash.write_now(offset, bytes).map_err(FileFlashError::Flash)?;
        self.persist(offset as usize, offset as usize + bytes.len()).await
    }
}
