//! The update session: [`UpdateService`] takes a client through the greeting and its proof,
//! the image header, the firmware streamed a chunk at a time and the finish (verified and
//! marked), and the web console's upload steps ([`UpdateService::web_step`], feature `web`).

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{with_timeout, Duration};
use embedded_io_async::{Read, Write};
use embedded_storage_async::nor_flash::NorFlash;

use remodaq_protocol::auth::server_signature;
use remodaq_protocol::update::{
    answer_message, auth_message, Greeting, Header, Status, HANDSHAKE_S, HEADER_LEN, OPENING,
};
use remodaq_shared::module::{CommonSettings, SettingsAccess, Store};
use remodaq_shared::password::{Check, AUTH, KEY_LEN, NONCE_LEN};
#[cfg(feature = "web")]
use remodaq_shared::upload::{WebDone, WebStep, WEB_CHUNK};

use crate::io::{read_exact, send, send_signed};
use crate::target::UpdateTarget;

/// Firmware bytes buffered per write to the update partition.
pub const CHUNK: usize = 1024;

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
        // Nothing is read as a proof from a stream that does not open as a session does (an
        // HTTP request from a browser page, security review finding 7): closed at once.
        let mut opening = [0u8; OPENING.len()];
        read_exact(io, &mut opening).await.ok_or(Refused::Gone)?;
        if opening != OPENING {
            remodaq_shared::warn!("update: a connection that is not an update session, closed");
            return Err(Refused::Gone);
        }
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
    remodaq_shared::module::commit_counters(map, store, |s| {
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
