//! Where an update goes: the [`UpdateTarget`] a session writes, verifies and marks an image in.

use remodaq_protocol::update::{Header, Status};

/// Where an update goes: the bootloader's update partition and state (`embassy-boot`'s
/// `FirmwareUpdater` on the boards).
#[allow(async_fn_in_trait)]
pub trait UpdateTarget {
    /// Write granularity of the update partition: every write but the last is a multiple.
    const WRITE_SIZE: usize;
    /// Starts a session: erases the update partition (whatever an earlier, cut session left).
    async fn begin(&mut self) -> Result<(), Status>;
    /// Writes firmware bytes at `offset` (erasing sectors as it goes).
    async fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Status>;
    /// Verifies the firmware written against `header` (its digest) and the header's signature
    /// against this module's key; `Err(BadSignature)` if they do not match.
    async fn verify(&mut self, header: &Header) -> Result<(), Status>;
    /// Marks the verified image for the bootloader to swap in at the next start, with its
    /// header (the manifest the bootloader checks again before the swap).
    async fn mark(&mut self, header: &Header) -> Result<(), Status>;
}
