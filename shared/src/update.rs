//! The module side of the firmware update service (`remodaq_protocol::update`, re-exported):
//! one session streams a signed image into the update (DFU) partition with a bounded buffer,
//! then has it verified and marked for the bootloader. A session cut at any point leaves the
//! running image, its state and the settings untouched, and can simply be started again.

pub use remodaq_protocol::update::*;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{with_timeout, Duration};
use embedded_io_async::{Read, Write};
use embedded_storage_async::nor_flash::NorFlash;

use crate::module::{CommonSettings, SettingsAccess};
use crate::password::{Check, Limiter, MAX_LEN};

include!(concat!(env!("OUT_DIR"), "/update_key.rs"));

/// How long a new image may take to pass its self-test before the module restarts (and the
/// bootloader reverts to the previous image).
pub const TRIAL: Duration = Duration::from_secs(20);

/// Firmware bytes buffered per write to the update partition.
pub const CHUNK: usize = 1024;
/// A session whose peer sends nothing for this long ends (the image stays unmarked).
pub const STALL: Duration = Duration::from_secs(10);

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
    /// Verifies the `length` bytes written against `signature` and this module's key, and if
    /// they match marks them for the bootloader to swap in at the next start.
    async fn verify_and_mark(&mut self, signature: &[u8; 64], length: u32) -> Result<(), Status>;
}

/// How a session ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Outcome {
    /// The image is verified and marked: restart into it.
    Updated {
        /// Its firmware version.
        version: u16,
    },
    /// Refused (the status was sent), or cut or stalled: nothing is marked.
    NotUpdated,
}

/// The update service of a module: its model, the size of its update partition, and its own
/// wrong-password limiter (per source address, as discovery's).
pub struct UpdateService {
    model: u16,
    capacity: u32,
    limiter: Limiter,
}

impl UpdateService {
    /// The service of a module with name register `model` and an update partition of
    /// `capacity` bytes.
    pub fn new(model: u16, capacity: u32) -> Self {
        Self { model, capacity, limiter: Limiter::default() }
    }

    /// Serves one session from the client at `from` at `now_ms`. The map is locked only to
    /// copy the password hash.
    pub async fn session<T, R, A, U>(
        &mut self,
        io: &mut T,
        from: [u8; 4],
        now_ms: u64,
        map: &Mutex<R, A>,
        target: &mut U,
    ) -> Outcome
    where
        T: Read + Write,
        R: RawMutex,
        A: SettingsAccess,
        U: UpdateTarget,
    {
        let mut buf = [0u8; CHUNK];
        // The password, then the image header.
        let Some(()) = read_exact(io, &mut buf[..1]).await else { return Outcome::NotUpdated };
        let len = usize::from(buf[0]);
        if len > MAX_LEN {
            return reply(io, Status::Invalid).await;
        }
        let mut password = [0u8; MAX_LEN];
        let Some(()) = read_exact(io, &mut password[..len]).await else { return Outcome::NotUpdated };
        let mut header = [0u8; HEADER_LEN];
        let Some(()) = read_exact(io, &mut header).await else { return Outcome::NotUpdated };
        let header = match Header::decode(&header) {
            Some(h) if h.model == self.model && h.length > 0 && h.length <= self.capacity => h,
            _ => return reply(io, Status::Invalid).await,
        };
        let hash = map.lock().await.settings().password();
        match self.limiter.check(&hash, &password[..len], from, now_ms) {
            Check::Ok => {}
            Check::Wrong => {
                crate::warn!("update: wrong configuration password");
                return reply(io, Status::WrongPassword).await;
            }
            Check::Locked => return reply(io, Status::RateLimited).await,
        }
        if let Err(status) = target.begin().await {
            crate::error!("update: the update partition could not be erased");
            return reply(io, status).await;
        }
        if !send(io, Status::Ok).await {
            return Outcome::NotUpdated;
        }
        crate::info!("update: receiving {} bytes, version {:04X}", header.length, header.version);

        // The firmware, a chunk at a time; the last one padded to the write size.
        let mut offset = 0u32;
        while offset < header.length {
            let n = ((header.length - offset) as usize).min(CHUNK);
            let Some(()) = read_exact(io, &mut buf[..n]).await else {
                crate::warn!("update: cut after {} bytes; nothing marked", offset);
                return Outcome::NotUpdated;
            };
            let padded = n.next_multiple_of(U::WRITE_SIZE).min(CHUNK);
            buf[n..padded].fill(0xFF);
            if let Err(status) = target.write(offset, &buf[..padded]).await {
                crate::error!("update: the update partition could not be written");
                return reply(io, status).await;
            }
            offset += n as u32;
        }
        match target.verify_and_mark(&header.signature, header.length).await {
            Ok(()) => {
                crate::info!("update: version {:04X} verified and marked", header.version);
                // Marked: the bootloader swaps it in at the next start, answer sent or not.
                send(io, Status::Ok).await;
                Outcome::Updated { version: header.version }
            }
            Err(status) => {
                crate::warn!("update: refused after verification: {}", status as u8);
                reply(io, status).await
            }
        }
    }
}

/// Sends a refusal: the session ends with nothing updated.
async fn reply<T: Write>(io: &mut T, status: Status) -> Outcome {
    send(io, status).await;
    Outcome::NotUpdated
}

/// Sends a status; false if it could not be sent in time.
async fn send<T: Write>(io: &mut T, status: Status) -> bool {
    let sent = with_timeout(STALL, async {
        io.write_all(&[status as u8]).await?;
        io.flush().await
    })
    .await;
    let ok = matches!(sent, Ok(Ok(())));
    if !ok {
        crate::warn!("update: the answer could not be sent");
    }
    ok
}

/// Fills `buf`; `None` if the peer closed, failed or stalled first.
async fn read_exact<T: Read>(io: &mut T, buf: &mut [u8]) -> Option<()> {
    let mut filled = 0;
    while filled < buf.len() {
        match with_timeout(STALL, io.read(&mut buf[filled..])).await {
            Ok(Ok(n)) if n > 0 => filled += n,
            _ => return None,
        }
    }
    Some(())
}

/// The update target of the boards: `embassy-boot`'s updater with this module's public key.
pub struct BootUpdater<'d, DFU: NorFlash, STATE: NorFlash> {
    /// The updater over the update and state partitions.
    pub updater: embassy_boot::FirmwareUpdater<'d, DFU, STATE>,
    /// The public key images are signed for.
    pub public_key: [u8; 32],
}

impl<DFU, STATE> UpdateTarget for BootUpdater<'_, DFU, STATE>
where
    DFU: NorFlash,
    STATE: NorFlash,
{
    const WRITE_SIZE: usize = DFU::WRITE_SIZE;

    async fn begin(&mut self) -> Result<(), Status> {
        // Fails too when the running image is not confirmed yet (no update on top of a trial).
        self.updater.prepare_update().await.map(|_| ()).map_err(|_| Status::StoreFailed)
    }

    async fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Status> {
        self.updater.write_firmware(offset as usize, data).await.map_err(|_| Status::StoreFailed)
    }

    async fn verify_and_mark(&mut self, signature: &[u8; 64], length: u32) -> Result<(), Status> {
        match self.updater.verify_and_mark_updated(&self.public_key, signature, length).await {
            Ok(()) => Ok(()),
            Err(embassy_boot::FirmwareUpdaterError::Signature(_)) => Err(Status::BadSignature),
            Err(_) => Err(Status::StoreFailed),
        }
    }
}

/// The self-test a new image must pass to confirm itself: the network up, the inputs valid
/// (the front end answers: first acquisition done, no front-end fault), and the settings store
/// working (no failed commit).
pub fn self_test_passed(network_up: bool) -> bool {
    use crate::diagnostics::{status, DIAGNOSTICS};
    let s = DIAGNOSTICS.status();
    network_up && s & (status::INPUTS_PENDING | status::FRONT_END_FAULT | status::STORE_FAULT) == 0
}

/// The update task of a board with a bootloader: confirms a new (or reverted-to) image once its
/// self-test passes, or restarts it (the bootloader then reverts) when it has not passed after
/// [`TRIAL`]; then serves update sessions forever on `net`.
pub async fn run<N, A, DFU, STATE>(
    net: &'static N,
    map: &'static crate::board::Shared<A>,
    model: u16,
    dfu: DFU,
    state: STATE,
) -> !
where
    N: crate::board::Network,
    A: SettingsAccess,
    DFU: NorFlash,
    STATE: NorFlash,
{
    // The updater's state buffer is STATE::WRITE_SIZE long: at most 32 bytes on the targets.
    const { assert!(STATE::WRITE_SIZE <= 32) };
    let mut aligned = [0u8; 32];
    // The update partition is the running one plus a page for the swap.
    let capacity = (dfu.capacity() - DFU::ERASE_SIZE) as u32;
    let updater = embassy_boot::FirmwareUpdater::new(
        embassy_boot::FirmwareUpdaterConfig { dfu, state },
        &mut aligned[..STATE::WRITE_SIZE],
    );
    let mut target = BootUpdater { updater, public_key: UPDATE_KEY };
    confirm(net, &mut target).await;
    let mut service = UpdateService::new(model, capacity);
    net.serve_update(map, &mut service, &mut target).await
}

async fn confirm<N, DFU, STATE>(net: &N, target: &mut BootUpdater<'_, DFU, STATE>)
where
    N: crate::board::Network,
    DFU: NorFlash,
    STATE: NorFlash,
{
    use embassy_boot::State;
    let state = target.updater.get_state().await;
    let what = match state {
        Ok(State::Swap) => "a new image",
        Ok(State::Revert) => "the previous image (the new one did not confirm itself)",
        Ok(_) => return,
        Err(_) => {
            crate::error!("update: the bootloader's state cannot be read");
            return;
        }
    };
    crate::info!("update: running {} on trial", what);
    let deadline = embassy_time::Instant::now() + TRIAL;
    loop {
        if self_test_passed(net.is_up()) && !cfg!(feature = "never-confirm") {
            match target.updater.mark_booted().await {
                Ok(()) => crate::info!("update: self-test passed, image confirmed"),
                Err(_) => crate::error!("update: the image could not be confirmed"),
            }
            return;
        }
        if embassy_time::Instant::now() > deadline {
            crate::error!("update: self-test not passed in time: restarting (the bootloader reverts)");
            net.restart().await;
        }
        embassy_time::Timer::after_millis(100).await;
    }
}
