//! One flash controller shared by the partitions on it: the settings, the update partition
//! (DFU) and the bootloader's state are regions of one flash, and on the STM32F429 reading a
//! bank while a sector of that same bank erases stalls the bus, CPU and interrupts included,
//! until the erase ends (RM0090 §3.6: only the *other* bank can be read meanwhile).
//!
//! [`Serialized`] wraps each partition: every read, every write and every *single sector's*
//! erase holds [`CONTROLLER`]. A settings read during an update therefore waits (async, the
//! executor running on) for at most one sector's erase, instead of stalling the CPU, and an
//! erase of a range lets other users in between its sectors (embassy-stm32 0.6 holds its own
//! flash lock for a whole range: seven 128 KiB sectors, up to 28 s at x8 parallelism).
//! docs/design.md ("Flash") has the figures.

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::{ErrorType, MultiwriteNorFlash, NorFlash, ReadNorFlash};

/// The lock of the module's one flash controller.
pub type Controller = Mutex<CriticalSectionRawMutex, ()>;

/// The flash controller of the firmware: every [`Serialized`] partition of a board takes it.
pub static CONTROLLER: Controller = Mutex::new(());

/// A partition whose every operation holds the controller's lock: reads and writes whole, erases
/// one sector at a time.
pub struct Serialized<F> {
    inner: F,
    controller: &'static Controller,
}

impl<F> Serialized<F> {
    /// `inner`, serialized with the other partitions on `controller` (the firmware's
    /// [`CONTROLLER`]).
    pub const fn new(inner: F, controller: &'static Controller) -> Self {
        Self { inner, controller }
    }

    /// The partition itself.
    pub fn into_inner(self) -> F {
        self.inner
    }
}

impl<F: ErrorType> ErrorType for Serialized<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Serialized<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let read = {
            let _controller = self.controller.lock().await;
            self.inner.read(offset, bytes).await
        };
        yield_to_waiters().await;
        read
    }

    fn capacity(&self) -> usize {
        self.inner.capacity()
    }
}

impl<F: NorFlash> NorFlash for Serialized<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    /// Erases `from..to` one sector at a time, the lock taken for each: a range never holds
    /// the controller for longer than one sector's erase.
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let sector = F::ERASE_SIZE as u32;
        let mut at = from;
        while at < to {
            let end = at.saturating_add(sector).min(to);
            {
                let _controller = self.controller.lock().await;
                self.inner.erase(at, end).await?;
            }
            yield_to_waiters().await;
            at = end;
        }
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let written = {
            let _controller = self.controller.lock().await;
            self.inner.write(offset, bytes).await
        };
        yield_to_waiters().await;
        written
    }
}

impl<F: MultiwriteNorFlash> MultiwriteNorFlash for Serialized<F> {}

/// After each operation (an erase, a write, a read), lets a task that waited for the controller
/// take it before this one asks again: embassy-sync's mutex is not first come, first served, and
/// a task that releases and locks again without yielding would keep it (the update service
/// writes sector after sector while a settings commit waits). The waiter was woken when the
/// lock was released, so it runs before this task is polled again. After a read too: a settings
/// lookup reads item after item (sequential-storage), all at once from a flash that answers at
/// once, and held the main executor 2.7-6 ms in one poll under QEMU as the settings grew (the
/// web console's, issue #40); now each read is a poll of its own.
async fn yield_to_waiters() {
    embassy_futures::yield_now().await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ram_flash::RamFlash;
    use core::future::Future;
    use embassy_futures::block_on;

    /// Counts the erase calls that reach the partition, and their ranges.
    struct Counting {
        flash: RamFlash<{ 4 * 1024 }, 1024>,
        erases: std::vec::Vec<(u32, u32)>,
        /// Whether the controller was held during each erase.
        held: std::vec::Vec<bool>,
    }

    static TEST_CONTROLLER: Controller = Mutex::new(());

    impl ErrorType for Counting {
        type Error = crate::ram_flash::RamFlashError;
    }
    impl ReadNorFlash for Counting {
        const READ_SIZE: usize = 1;
        async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
            ReadNorFlash::read(&mut self.flash, offset, bytes).await
        }
        fn capacity(&self) -> usize {
            4 * 1024
        }
    }
    impl NorFlash for Counting {
        const WRITE_SIZE: usize = 4;
        const ERASE_SIZE: usize = 1024;
        async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
            self.erases.push((from, to));
            self.held.push(TEST_CONTROLLER.try_lock().is_err());
            NorFlash::erase(&mut self.flash, from, to).await
        }
        async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
            NorFlash::write(&mut self.flash, offset, bytes).await
        }
    }

    #[test]
    fn a_range_is_erased_one_sector_at_a_time_under_the_lock() {
        let inner = Counting { flash: RamFlash::new(), erases: std::vec![], held: std::vec![] };
        let mut flash = Serialized::new(inner, &TEST_CONTROLLER);
        block_on(NorFlash::write(&mut flash, 1024, &[0; 8])).unwrap();
        block_on(NorFlash::erase(&mut flash, 0, 3 * 1024)).unwrap();
        let inner = flash.into_inner();
        assert_eq!(inner.erases, [(0, 1024), (1024, 2048), (2048, 3072)], "three single-sector erases");
        assert_eq!(inner.held, [true, true, true], "each under the controller's lock");
        assert_eq!(inner.flash.image()[1024], 0xFF, "erased");
        assert!(TEST_CONTROLLER.try_lock().is_ok(), "released after the range");
    }

    /// A flash whose every operation takes one poll (as an erase on the STM32 waits for its
    /// interrupt), logging the operations in order.
    struct Slow<'a> {
        name: &'static str,
        log: &'a core::cell::RefCell<std::vec::Vec<std::string::String>>,
    }
    impl ErrorType for Slow<'_> {
        type Error = core::convert::Infallible;
    }
    impl ReadNorFlash for Slow<'_> {
        const READ_SIZE: usize = 1;
        async fn read(&mut self, offset: u32, _bytes: &mut [u8]) -> Result<(), Self::Error> {
            embassy_futures::yield_now().await;
            self.log.borrow_mut().push(std::format!("{} read {offset}", self.name));
            Ok(())
        }
        fn capacity(&self) -> usize {
            4096
        }
    }
    impl NorFlash for Slow<'_> {
        const WRITE_SIZE: usize = 4;
        const ERASE_SIZE: usize = 1024;
        async fn erase(&mut self, from: u32, _to: u32) -> Result<(), Self::Error> {
            embassy_futures::yield_now().await;
            self.log.borrow_mut().push(std::format!("{} erase {from}", self.name));
            Ok(())
        }
        async fn write(&mut self, offset: u32, _bytes: &[u8]) -> Result<(), Self::Error> {
            embassy_futures::yield_now().await;
            self.log.borrow_mut().push(std::format!("{} write {offset}", self.name));
            Ok(())
        }
    }

    /// Issue #21: a settings read that arrives while the update partition erases sector after
    /// sector gets the controller after the sector being erased, not after the whole range.
    #[test]
    fn a_waiting_partition_goes_between_two_sectors_of_another() {
        static FAIR: Controller = Mutex::new(());
        let log = core::cell::RefCell::new(std::vec::Vec::new());
        let mut dfu = Serialized::new(Slow { name: "dfu", log: &log }, &FAIR);
        let mut settings = Serialized::new(Slow { name: "settings", log: &log }, &FAIR);
        let mut buf = [0u8; 4];
        block_on(embassy_futures::join::join(
            NorFlash::erase(&mut dfu, 0, 3 * 1024),
            ReadNorFlash::read(&mut settings, 0, &mut buf),
        ));
        assert_eq!(*log.borrow(), ["dfu erase 0", "settings read 0", "dfu erase 1024", "dfu erase 2048"]);
    }

    #[test]
    fn a_read_waits_while_another_partition_holds_the_controller() {
        static LOCAL: Controller = Mutex::new(());
        let mut flash = Serialized::new(RamFlash::<1024, 1024>::new(), &LOCAL);
        let held = LOCAL.try_lock().unwrap();
        let mut buf = [0u8; 4];
        let mut read = core::pin::pin!(ReadNorFlash::read(&mut flash, 0, &mut buf));
        let waker = core::task::Waker::noop().clone();
        let mut cx = core::task::Context::from_waker(&waker);
        assert!(read.as_mut().poll(&mut cx).is_pending(), "waits for the controller");
        drop(held);
        // It reads, then lets the executor's other tasks run once: a settings lookup, which reads
        // item after item, never holds the executor for its whole scan (issue #40).
        assert!(read.as_mut().poll(&mut cx).is_pending(), "reads, then yields");
        assert!(matches!(read.as_mut().poll(&mut cx), core::task::Poll::Ready(Ok(()))), "then returns");
    }
}
