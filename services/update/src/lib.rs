//! The firmware update service (docs/update.md; the codec is `remodaq_protocol::update`,
//! re-exported): one session streams a signed image into the update (DFU) partition with a
//! bounded buffer, then has it verified and marked for the bootloader. A session cut at any
//! point leaves the running image, its state and the settings untouched, and can simply be
//! started again. [`start`] confirms a new image on trial; [`embassy`] (feature `embassy-net`)
//! serves the sessions on an embassy-net socket, and the web console's uploads between them.
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

#[cfg(feature = "embassy-net")]
pub mod embassy;

pub use remodaq_protocol::update::*;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{with_timeout, Duration};
use embedded_io_async::{Read, Write};
use embedded_storage_async::nor_flash::NorFlash;

use remodaq_shared::board::{Network, Shared};
use remodaq_shared::module::{CommonSettings, SettingsAccess, Store};
#[cfg(feature = "web")]
use remodaq_shared::upload::{WebDone, WebStep, WEB_CHUNK};
use remodaq_shared::password::{Check, AUTH, KEY_LEN, NONCE_LEN};
use remodaq_protocol::auth::server_signature;

/// How long a new image may take to pass its self-test before the module restarts (and the
/// bootloader reverts to the previous image).
pub const TRIAL: Duration = Duration::from_secs(20);

/// Firmware bytes buffered per write to the update partition.
pub const CHUNK: usize = 1024;
/// A session whose peer sends nothing for this long ends (the image stays unmarked).
pub const STALL: Duration = Duration::from_secs(HANDSHAKE_S);

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

/// The update service of a module: its model, MAC and the size of its update partition.
/// Wrong proofs count against the module-wide guessing budget (`remodaq_shared::password::AUTH`).
pub struct UpdateService {
    model: u16,
    mac: [u8; 6],
    capacity: u32,
    /// An upload through the web console under way: its header and the bytes written. A
    /// session that begins writing the partition ends it (its bytes are overwritten).
    #[cfg(feature = "web")]
    upload: Option<(Header, u32)>,
}

/// Why a session's handshake ended without going on.
enum Refused {
    /// The peer went, stalled or took too long: nothing to answer.
    Gone,
    /// Refused before a right proof (unsigned answer).
    Early(Status),
    /// Refused after a right proof (signed answer).
    Late(Status),
}

impl UpdateService {
    /// The service of a module with name register `model`, MAC `mac` and an update partition
    /// of `capacity` bytes.
    pub fn new(model: u16, mac: [u8; 6], capacity: u32) -> Self {
        Self {
            model,
            mac,
            capacity,
            #[cfg(feature = "web")]
            upload: None,
        }
    }

    /// Serves one session from the client at `from` at `now_ms`. The map is locked only to
    /// copy the credential.
    #[allow(clippy::too_many_arguments)]
    pub async fn session<T, R, A, F, U>(
        &mut self,
        io: &mut T,
        from: [u8; 4],
        now_ms: u64,
        map: &Mutex<R, A>,
        store: &Store<F, A::Settings>,
        target: &mut U,
    ) -> Outcome
    where
        T: Read + Write,
        R: RawMutex,
        A: SettingsAccess,
        F: NorFlash,
        U: UpdateTarget,
    {
        let settings = *map.lock().await.settings();
        let credential = settings.password();
        let mut cnonce = [0u8; NONCE_LEN];
        let mut snonce = [0u8; NONCE_LEN];
        let mut context = [0u8; 12];
        context[..8].copy_from_slice(&now_ms.to_le_bytes());
        context[8..].copy_from_slice(&from);
        AUTH.random(&context, &mut snonce);
        let mut header = [0u8; HEADER_LEN];
        let handshake = self.handshake(io, from, now_ms, &settings, &mut cnonce, &snonce, &mut header);
        let refused = match with_timeout(Duration::from_secs(HANDSHAKE_S), handshake).await {
            Ok(Ok(h)) => Ok(h),
            Ok(Err(refused)) => Err(refused),
            Err(_) => Err(Refused::Gone),
        };
        let message = auth_message(&self.mac, &cnonce, &snonce, &header);
        let sign = |step: u8, status: Status| {
            server_signature(&credential.server_key, &answer_message(&message, &[step], &[status as u8]))
        };
        let header = match refused {
            Ok(h) => h,
            Err(Refused::Gone) => return Outcome::NotUpdated,
            Err(Refused::Early(status)) => {
                refused_update(from);
                send(io, &[status as u8]).await;
                return Outcome::NotUpdated;
            }
            Err(Refused::Late(status)) => {
                refused_update(from);
                return answer(io, status, &sign(0, status)).await;
            }
        };
        // Only an authenticated session that begins writing ends an upload of the console's:
        // a connection alone leaves it.
        #[cfg(feature = "web")]
        {
            self.upload = None;
        }
        if let Err(status) = target.begin().await {
            remodaq_shared::error!("update: the update partition could not be erased");
            return answer(io, status, &sign(0, status)).await;
        }
        if !send_signed(io, Status::Ok, &sign(0, Status::Ok)).await {
            return Outcome::NotUpdated;
        }
        remodaq_shared::info!("update: receiving {} bytes, version {:04X}", header.length, header.version);

        // The firmware, a chunk at a time; the last one padded to the write size.
        let mut buf = [0u8; CHUNK];
        let mut offset = 0u32;
        while offset < header.length {
            let n = ((header.length - offset) as usize).min(CHUNK);
            let Some(()) = read_exact(io, &mut buf[..n]).await else {
                remodaq_shared::warn!("update: cut after {} bytes; nothing marked", offset);
                return Outcome::NotUpdated;
            };
            let padded = n.next_multiple_of(U::WRITE_SIZE).min(CHUNK);
            buf[n..padded].fill(0xFF);
            if let Err(status) = target.write(offset, &buf[..padded]).await {
                remodaq_shared::error!("update: the update partition could not be written");
                return answer(io, status, &sign(1, status)).await;
            }
            offset += n as u32;
        }
        match finish(&header, map, store, target).await {
            Ok(()) => {
                remodaq_shared::info!("update: version {:04X} verified and marked", header.version);
                // Marked: the bootloader swaps it in at the next start, answer sent or not.
                send_signed(io, Status::Ok, &sign(1, Status::Ok)).await;
                Outcome::Updated { version: header.version }
            }
            Err(status) => {
                remodaq_shared::warn!("update: refused after verification: {}", status as u8);
                refused_update(from);
                answer(io, status, &sign(1, status)).await
            }
        }
    }

    /// Steps 1-3 of a session: the PC's nonce, the greeting, the proof and the header, checked.
    #[allow(clippy::too_many_arguments)]
    async fn handshake<T: Read + Write, S: CommonSettings>(
        &self,
        io: &mut T,
        from: [u8; 4],
        now_ms: u64,
        settings: &S,
        cnonce: &mut [u8; NONCE_LEN],
        snonce: &[u8; NONCE_LEN],
        header: &mut [u8; HEADER_LEN],
    ) -> Result<Header, Refused> {
        let credential = settings.password();
        read_exact(io, cnonce).await.ok_or(Refused::Gone)?;
        let mut flags = 0;
        if credential.is_factory() {
            flags |= remodaq_protocol::discovery::info_flags::FACTORY_PASSWORD;
        }
        let greeting = Greeting {
            mac: self.mac,
            salt: credential.salt,
            iterations: credential.iterations,
            snonce: *snonce,
            flags,
        };
        if !send(io, &greeting.encode()).await {
            return Err(Refused::Gone);
        }
        let mut proof = [0u8; KEY_LEN];
        read_exact(io, &mut proof).await.ok_or(Refused::Gone)?;
        read_exact(io, header).await.ok_or(Refused::Gone)?;
        let message = auth_message(&self.mac, cnonce, snonce, header);
        match AUTH.check(&credential, &message, &proof, from, now_ms) {
            Check::Ok(_) => {}
            Check::Wrong => return Err(Refused::Early(Status::WrongPassword)),
            Check::Limited => return Err(Refused::Early(Status::RateLimited)),
        }
        if credential.is_factory() {
            remodaq_shared::warn!("update: refused, the factory password is in force");
            return Err(Refused::Late(Status::SetPasswordFirst));
        }
        self.check_header(header, settings).map_err(Refused::Late)
    }

    /// An image header, checked: for this model, of a length the update partition holds, and
    /// its security counter not below the module's (`Downgrade`); `Invalid` otherwise.
    fn check_header<S: CommonSettings>(&self, header: &[u8; HEADER_LEN], settings: &S) -> Result<Header, Status> {
        match Header::decode(header) {
            Some(h) if h.model == self.model && h.length > 0 && h.length <= self.capacity => {
                let confirmed = settings.update_counter().confirmed;
                if h.counter < confirmed {
                    remodaq_shared::warn!("update: refused, counter {} below the module's {}", h.counter, confirmed);
                    return Err(Status::Downgrade);
                }
                Ok(h)
            }
            _ => Err(Status::Invalid),
        }
    }

    /// Carries out one step of an upload through the web console (its request signed by a
    /// session of a password that is not the factory one: `web::firmware`), as a session of
    /// this service would: the header checked and the partition made ready, the firmware
    /// written a chunk at a time in order, then verified and marked. `upload` is the upload
    /// under way (its header and the bytes written); a session of this service ends it.
    #[cfg(feature = "web")]
    pub async fn web_step<R, A, F, U>(
        &mut self,
        step: &WebStep,
        map: &Mutex<R, A>,
        store: &Store<F, A::Settings>,
        target: &mut U,
    ) -> Result<WebDone, Status>
    where
        R: RawMutex,
        A: SettingsAccess,
        F: NorFlash,
        U: UpdateTarget,
    {
        match step {
            WebStep::Begin(bytes) => {
                self.upload = None;
                let settings = *map.lock().await.settings();
                let header = self.check_header(bytes, &settings)?;
                target.begin().await?;
                remodaq_shared::info!("update: receiving {} bytes from the web console", header.length);
                self.upload = Some((header, 0));
                Ok(WebDone::Begun(header))
            }
            WebStep::Write { offset, len, data } => {
                let Some((header, written)) = self.upload.as_mut() else { return Ok(WebDone::NoUpload) };
                let expected = ((header.length - *written) as usize).min(WEB_CHUNK);
                if *offset != *written || *len != expected {
                    return Err(Status::Invalid);
                }
                let mut padded = [0xFFu8; WEB_CHUNK];
                padded[..*len].copy_from_slice(&data[..*len]);
                let end = len.next_multiple_of(U::WRITE_SIZE).min(WEB_CHUNK);
                if let Err(status) = target.write(*offset, &padded[..end]).await {
                    self.upload = None;
                    return Err(status);
                }
                *written += *len as u32;
                Ok(WebDone::Written(*written))
            }
            WebStep::Finish => {
                let Some((header, written)) = self.upload.take() else { return Ok(WebDone::NoUpload) };
                if written != header.length {
                    self.upload = Some((header, written));
                    return Err(Status::Invalid);
                }
                finish(&header, map, store, target).await?;
                remodaq_shared::info!("update: version {:04X} verified and marked (web console)", header.version);
                Ok(WebDone::Updated(header))
            }
        }
    }
}

/// Verifies an image written whole, keeps its counter until it confirms itself, and marks it
/// for the bootloader.
async fn finish<R, A, F, U>(
    header: &Header,
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    target: &mut U,
) -> Result<(), Status>
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
    U: UpdateTarget,
{
    target.verify(header).await?;
    // The counter of the image to come, kept until it confirms itself.
    remodaq_shared::module::commit_change(map, store, |s| {
        let mut c = s.update_counter();
        c.pending = header.counter;
        s.set_update_counter(c);
    })
    .await
    .map_err(|_| Status::StoreFailed)?;
    target.mark(header).await
}

fn refused_update(from: [u8; 4]) {
    remodaq_shared::diagnostics::DIAGNOSTICS.security(remodaq_shared::diagnostics::Security::UpdateRefusal, from);
}

/// Sends a signed refusal: the session ends with nothing updated.
async fn answer<T: Write>(io: &mut T, status: Status, signature: &[u8; KEY_LEN]) -> Outcome {
    send_signed(io, status, signature).await;
    Outcome::NotUpdated
}

/// Sends a status and its signature; false if it could not be sent in time.
async fn send_signed<T: Write>(io: &mut T, status: Status, signature: &[u8; KEY_LEN]) -> bool {
    let mut bytes = [0u8; SIGNED_ANSWER_LEN];
    bytes[0] = status as u8;
    bytes[1..].copy_from_slice(signature);
    send(io, &bytes).await
}

/// Sends bytes; false if they could not be sent in time.
async fn send<T: Write>(io: &mut T, bytes: &[u8]) -> bool {
    let sent = with_timeout(STALL, async {
        io.write_all(bytes).await?;
        io.flush().await
    })
    .await;
    let ok = matches!(sent, Ok(Ok(())));
    if !ok {
        remodaq_shared::warn!("update: the answer could not be sent");
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
    state: embassy_boot::FirmwareState<'d, STATE>,
    public_key: [u8; 32],
    manifest_at: u32,
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
        match header.verify(&hash.finalize(), &self.public_key) {
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

/// The self-test a new image must pass to confirm itself: the network up, the inputs valid
/// (the front end answers: first acquisition done, no front-end fault), and the settings store
/// working (no failed commit).
pub fn self_test_passed(network_up: bool) -> bool {
    use remodaq_shared::diagnostics::{status, DIAGNOSTICS};
    let s = DIAGNOSTICS.status();
    network_up && s & (status::INPUTS_PENDING | status::FRONT_END_FAULT | status::STORE_FAULT) == 0
}

/// The start of the update task of a board with a bootloader: confirms a new (or reverted-to)
/// image once its self-test passes, or restarts it (the bootloader then reverts) when it has not
/// passed after [`TRIAL`]. Returns the update partition's writer (over `aligned`, the state
/// partition's write buffer) and the service, which then serve update sessions forever on the
/// board's network ([`embassy::serve`] on the embassy-net boards).
#[allow(clippy::too_many_arguments)]
pub async fn start<'d, N, A, F, DFU, STATE>(
    net: &'static N,
    map: &'static Shared<A>,
    store: &'static Store<F, A::Settings>,
    model: u16,
    mac: [u8; 6],
    dfu: DFU,
    state: STATE,
    aligned: &'d mut [u8; 32],
) -> (BootUpdater<'d, DFU, STATE>, UpdateService)
where
    N: Network,
    A: SettingsAccess,
    F: NorFlash,
    DFU: NorFlash,
    STATE: NorFlash,
{
    // The state buffer is STATE's write size: at most 32 bytes on the targets.
    const { assert!(STATE::WRITE_SIZE <= 32 && STATE::READ_SIZE <= STATE::WRITE_SIZE) };
    // The update partition is the running one plus a page for the swap.
    let capacity = (dfu.capacity() - DFU::ERASE_SIZE) as u32;
    let mut target =
        BootUpdater::new(dfu, state, &mut aligned[..STATE::WRITE_SIZE], remodaq_shared::identity::update_key(), capacity);
    let self_test = || self_test_passed(net.is_up()) && !cfg!(feature = "never-confirm");
    if confirm(&mut target, map, store, self_test, TRIAL).await == Confirmation::NotPassed {
        remodaq_shared::error!("update: self-test not passed in time: restarting (the bootloader reverts)");
        net.restart().await;
    }
    #[cfg(feature = "test-unsigned-swap")]
    forge_unsigned_swap(net, &mut target).await;
    (target, UpdateService::new(model, mac, capacity))
}

/// Test images only (feature `test-unsigned-swap`, the QEMU check of the bootloader): once
/// confirmed, the image writes junk into the update partition with a manifest whose signature
/// is not the key's, marks it for a swap and restarts, as code that took over the module might.
/// The bootloader must refuse the swap: this same image starts again, finds its junk there and
/// goes on serving.
#[cfg(feature = "test-unsigned-swap")]
async fn forge_unsigned_swap<N, DFU, STATE>(net: &N, target: &mut BootUpdater<'_, DFU, STATE>)
where
    N: Network,
    DFU: NorFlash,
    STATE: NorFlash,
{
    const MARK: &[u8; 8] = b"RDQ-JUNK";
    let mut first = [0u8; 8];
    if target.read_dfu(0, &mut first).await.is_ok() && first == *MARK {
        remodaq_shared::warn!("update: the forged swap was refused: still running this image");
        return;
    }
    let mut junk = [0xA5u8; 4096];
    junk[..8].copy_from_slice(MARK);
    let digest = salty::Sha512::new().updated(&junk).finalize();
    let forged =
        Header { model: 0x8350, version: 0xFFFF, counter: u32::MAX, length: 4096, digest, signature: [0x42; 64] };
    let mut manifest = [0xFFu8; MANIFEST_LEN];
    manifest[..HEADER_LEN].copy_from_slice(&forged.encode());
    let manifest_at = target.manifest_at;
    let written = async {
        target.begin().await?;
        target.write(0, &junk).await?;
        target.write(manifest_at, &manifest).await?;
        target.state.mark_updated().await.map_err(|_| Status::StoreFailed)
    };
    match written.await {
        Ok(()) => {
            remodaq_shared::warn!("update: junk with a forged manifest marked for a swap: restarting");
            net.restart().await
        }
        Err(_) => remodaq_shared::error!("update: the forged swap could not be written"),
    }
}

/// What [`confirm`] found at the start, and did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Confirmation {
    /// The image was confirmed before: nothing to do.
    Confirmed,
    /// A new image passed its self-test within its trial and is confirmed now.
    Passed,
    /// The bootloader reverted to this (previous, once confirmed) image: marked booted without
    /// a trial. The bootloader does nothing more in this state, so a trial that failed would
    /// only restart this same image for ever.
    Reverted,
    /// A new image did not pass its self-test within its trial: the caller restarts the module
    /// and the bootloader reverts to the previous image.
    NotPassed,
    /// The bootloader's state cannot be read.
    Unreadable,
}

/// Confirms the running image after a swap once `self_test` passes, within `trial`; confirms an
/// image the bootloader reverted to at once; and keeps the security counters in the settings
/// (anti-rollback, docs/update.md).
pub async fn confirm<A, F, DFU, STATE>(
    target: &mut BootUpdater<'_, DFU, STATE>,
    map: &Shared<A>,
    store: &Store<F, A::Settings>,
    mut self_test: impl FnMut() -> bool,
    trial: Duration,
) -> Confirmation
where
    A: SettingsAccess,
    F: NorFlash,
    DFU: NorFlash,
    STATE: NorFlash,
{
    use embassy_boot::State;
    // The counters once the image in the state `reverted` (or not) is confirmed: a new image's
    // counter becomes the module's; after a revert, the pending one is dropped.
    let settle = |reverted: bool| {
        move |s: &mut A::Settings| {
            let mut c = s.update_counter();
            if !reverted {
                c.confirmed = c.confirmed.max(c.pending);
            }
            c.pending = 0;
            s.set_update_counter(c);
        }
    };
    match target.state().await {
        Ok(State::Swap) => remodaq_shared::info!("update: running a new image on trial"),
        Ok(State::Revert) => {
            remodaq_shared::warn!("update: the new image did not confirm itself; running the previous one");
            if target.mark_booted().await.is_err() {
                remodaq_shared::error!("update: the previous image could not be confirmed");
            }
            if remodaq_shared::module::commit_change(map, store, settle(true)).await.is_err() {
                remodaq_shared::error!("update: the counters could not be stored");
            }
            return Confirmation::Reverted;
        }
        Ok(_) => return Confirmation::Confirmed,
        Err(_) => {
            remodaq_shared::error!("update: the bootloader's state cannot be read");
            return Confirmation::Unreadable;
        }
    }
    let deadline = embassy_time::Instant::now() + trial;
    loop {
        if self_test() {
            if target.mark_booted().await.is_ok() {
                remodaq_shared::info!("update: self-test passed, image confirmed");
                // Anti-rollback: from now on, images below this one's counter are refused.
                if remodaq_shared::module::commit_change(map, store, settle(false)).await.is_err() {
                    remodaq_shared::error!("update: the security counter could not be stored");
                }
                return Confirmation::Passed;
            }
            // Tried again until the trial ends; then the restart reverts, and the counter never
            // moved.
            remodaq_shared::error!("update: the image could not be confirmed");
        }
        if embassy_time::Instant::now() > deadline {
            return Confirmation::NotPassed;
        }
        embassy_time::Timer::after_millis(100).await;
    }
}
