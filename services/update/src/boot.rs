//! The boards' update target: [`BootUpdater`] over the bootloader's update partition and state,
//! and the manifest it writes for the bootloader.

use embedded_storage_async::nor_flash::NorFlash;

use remodaq_protocol::update::{Header, Status, HEADER_LEN};

use crate::target::UpdateTarget;

/// Bytes of the manifest written for the bootloader: the header, padded to a multiple of
/// every flash's write size (4 on the STM32 and the QEMU board, up to 32).
pub const MANIFEST_LEN: usize = HEADER_LEN.next_multiple_of(32);

/// The update target of the boards: the bootloader's update partition, written here directly
/// (each of its sectors erased once per session, just before its first write), and its state
/// through embassy-boot's [`FirmwareState`](embassy_boot::FirmwareState); images are checked
/// against this module's public key.
///
/// embassy-boot's `FirmwareUpdater` is not used for the partition: its `prepare_update` erases
/// every sector in one call (on the STM32, seven 128 KiB sectors under embassy-stm32's flash
/// lock: up to 28 s in which a settings write waits), and its `write_firmware` then erases each
/// sector a second time.
pub struct BootUpdater<'d, DFU: NorFlash, STATE: NorFlash> {
    dfu: DFU,
    pub(crate) state: embassy_boot::FirmwareState<'d, STATE>,
    public_key: [u8; 32],
    pub(crate) manifest_at: u32,
    /// The sectors of the update partition erased in this session (bit n: sector n).
    erased: u64,
}

/// Bytes hashed between two yields to the executor while an image is verified: about 30 µs
/// of SHA-512 on the Cortex-M4 at 180 MHz, so the 8350's output ring (refilled every 6.4 ms)
/// never waits behind a verification. The chunk lives in the update task's (static) future:
/// 1 KiB took the 8350 over its RAM goal (scripts/size-report).
pub const HASH_CHUNK: usize = 256;

impl<'d, DFU: NorFlash, STATE: NorFlash> BootUpdater<'d, DFU, STATE> {
    /// The target over the update partition `dfu` and the state partition `state`
    /// (`aligned`: a buffer of `STATE`'s write size, as embassy-boot asks), for images signed
    /// with `public_key`; the manifest goes at `manifest_at`, the start of `dfu`'s last page.
    pub fn new(dfu: DFU, state: STATE, aligned: &'d mut [u8], public_key: [u8; 32], manifest_at: u32) -> Self {
        let state = embassy_boot::FirmwareState::new(state, aligned);
        Self { dfu, state, public_key, manifest_at, erased: 0 }
    }

    /// The bootloader's state.
    pub async fn state(&mut self) -> Result<embassy_boot::State, Status> {
        self.state.get_state().await.map_err(|_| Status::StoreFailed)
    }

    /// Marks the running image booted (confirmed: no revert at the next start).
    pub async fn mark_booted(&mut self) -> Result<(), Status> {
        self.state.mark_booted().await.map_err(|_| Status::StoreFailed)
    }

    /// Reads the update partition.
    pub async fn read_dfu(&mut self, offset: u32, buf: &mut [u8]) -> Result<(), Status> {
        self.dfu.read(offset, buf).await.map_err(|_| Status::StoreFailed)
    }
}

impl<DFU, STATE> UpdateTarget for BootUpdater<'_, DFU, STATE>
where
    DFU: NorFlash,
    STATE: NorFlash,
{
    const WRITE_SIZE: usize = DFU::WRITE_SIZE;

    async fn begin(&mut self) -> Result<(), Status> {
        // No update on top of a trial: the running image must be confirmed (or the one the
        // bootloader reverted to).
        match self.state().await? {
            embassy_boot::State::Boot | embassy_boot::State::Revert => {}
            _ => return Err(Status::StoreFailed),
        }
        // Whatever an earlier, cut session left is erased sector by sector as this one writes.
        self.erased = 0;
        Ok(())
    }

    async fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Status> {
        let sector = DFU::ERASE_SIZE as u32;
        let end = offset.checked_add(data.len() as u32).ok_or(Status::StoreFailed)?;
        if data.is_empty() {
            return Ok(());
        }
        for n in offset / sector..=(end - 1) / sector {
            let bit = 1u64.checked_shl(n).ok_or(Status::StoreFailed)?;
            if self.erased & bit == 0 {
                let from = n * sector;
                self.dfu.erase(from, from + sector).await.map_err(|_| Status::StoreFailed)?;
                self.erased |= bit;
            }
        }
        self.dfu.write(offset, data).await.map_err(|_| Status::StoreFailed)
    }

    async fn verify(&mut self, header: &Header) -> Result<(), Status> {
        // The digest of what is in the partition (read back), as the bootloader will see it,
        // yielding between chunks.
        let mut hash = salty::Sha512::new();
        let mut chunk = [0u8; HASH_CHUNK];
        let mut offset = 0u32;
        while offset < header.length {
            let n = ((header.length - offset) as usize).min(chunk.len());
            self.read_dfu(offset, &mut chunk[..n]).await?;
            hash.update(&chunk[..n]);
            offset += n as u32;
            embassy_futures::yield_now().await;
        }
        match verified(header, &hash.finalize(), &self.public_key).await {
            true => Ok(()),
            false => Err(Status::BadSignature),
        }
    }

    async fn mark(&mut self, header: &Header) -> Result<(), Status> {
        // The manifest at the start of the partition's last page (the swap's scratch page,
        // beyond any firmware), where the bootloader reads it before the swap.
        let mut manifest = [0xFFu8; MANIFEST_LEN];
        manifest[..HEADER_LEN].copy_from_slice(&header.encode());
        self.write(self.manifest_at, &manifest).await?;
        self.state.mark_updated().await.map_err(|_| Status::StoreFailed)
    }
}

/// [`Header::verify`] by the worker off the main executor (`remodaq_shared::offload`): an
/// ed25519 check holds a processor for milliseconds.
async fn verified(header: &Header, digest: &[u8; 64], key: &[u8; 32]) -> bool {
    use remodaq_shared::offload::{run, Bytes, BYTES};
    const DIGEST: usize = HEADER_LEN;
    const KEY: usize = DIGEST + 64;
    const _: () = assert!(KEY + 32 <= BYTES);
    fn compute(bytes: &mut Bytes) {
        let header = bytes[..HEADER_LEN].try_into().ok().and_then(Header::decode);
        let digest: Option<[u8; 64]> = bytes[DIGEST..KEY].try_into().ok();
        let key: Option<[u8; 32]> = bytes[KEY..KEY + 32].try_into().ok();
        let good = match (header, digest, key) {
            (Some(header), Some(digest), Some(key)) => header.verify(&digest, &key),
            _ => false,
        };
        bytes[0] = u8::from(good);
    }
    let mut bytes = [0u8; BYTES];
    bytes[..HEADER_LEN].copy_from_slice(&header.encode());
    bytes[DIGEST..KEY].copy_from_slice(digest);
    bytes[KEY..KEY + 32].copy_from_slice(key);
    run(compute, bytes).await[0] == 1
}
