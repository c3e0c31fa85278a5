//! The discovery and configuration service (spec §1.4): [`Service::handle`] turns one datagram
//! into at most one reply and an effect for the board; [`serve`] runs it on any datagram socket,
//! and [`embassy`] (feature `embassy-net`) on an embassy-net UDP socket (the STM32 and QEMU
//! boards; the host board has its own). The codec is `remodaq_protocol::discovery` (re-exported
//! here).
#![no_std]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

#[cfg(feature = "embassy-net")]
pub mod embassy;

pub use remodaq_protocol::discovery::*;
pub use remodaq_shared::board::Effect;
pub use remodaq_shared::identity::Identity;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;

use remodaq_protocol::auth::{fingerprint, open_credential};
use remodaq_shared::access::AllowList;
use remodaq_shared::budget::Budget;
use remodaq_shared::module::{commit_change, CommonSettings, SettingsAccess, Store};
use remodaq_shared::net::NETWORK_STORED;
use remodaq_shared::nonces::Nonces;
use remodaq_shared::offload::{key_pair, x25519};
use remodaq_shared::password::{Check, Credential, AUTH, KEY_LEN};
use remodaq_shared::settings::StoreError;

/// Nonces handed out and not used yet.
pub const NONCES: usize = 16;

/// The module side of the protocol.
pub struct Service {
    identity: Identity,
    nonces: Nonces<NONCES>,
    /// The module's X25519 key for sealing a new credential (secret, public): new at start-up
    /// and after each password change.
    agreement: Option<([u8; KEY_LEN], [u8; KEY_LEN])>,
}

impl Service {
    /// The service of a module.
    pub fn new(identity: Identity) -> Self {
        Self { identity, nonces: Nonces::new(NONCE_LIFETIME_S * 1000), agreement: None }
    }

    /// The key-agreement key, taken when first needed (made ahead by the worker off the main
    /// executor, `remodaq_shared::offload::key_pair`).
    fn agreement(&mut self, now_ms: u64) -> ([u8; KEY_LEN], [u8; KEY_LEN]) {
        *self.agreement.get_or_insert_with(|| key_pair(&now_ms.to_le_bytes()))
    }

    /// Handles one datagram from `from` at `now_ms` (ms since start): the reply's length in
    /// `out` (none for datagrams that are ignored or addressed to another module) and the
    /// effect to carry out after sending it. The map is locked only to copy the settings in
    /// force: proofs are checked, and new settings committed, without its lock.
    pub async fn handle<R: RawMutex, A: SettingsAccess, F: NorFlash>(
        &mut self,
        datagram: &[u8],
        from: [u8; 4],
        now_ms: u64,
        map: &Mutex<R, A>,
        store: &Store<F, A::Settings>,
        out: &mut [u8],
    ) -> Option<(usize, Effect)> {
        let (id, request) = decode_request(datagram)?;
        let me = self.identity.mac;
        let current = *map.lock().await.settings();
        let credential = current.password();
        let (auth, command) = match request {
            Request::Search => return self.info(id, now_ms, &current, out).map(|n| (n, Effect::None)),
            Request::Identify { mac } if mac == me => {
                return result(out, op::IDENTIFY, id, me, Status::Ok, None).map(|n| (n, Effect::Identify));
            }
            Request::Challenge { mac, cnonce } if mac == me => {
                let snonce = self.nonces.issue(from, now_ms);
                let (_, public) = self.agreement(now_ms);
                let c = Challenge {
                    id,
                    mac: me,
                    cnonce,
                    snonce,
                    salt: credential.salt,
                    iterations: credential.iterations,
                    public,
                    flags: flags(&current),
                };
                return encode_challenge(&c, out).map(|n| (n, Effect::None));
            }
            Request::Command { mac, auth, command } if mac == me => (auth, command),
            _ => return None,
        };
        let opcode = command.opcode();
        let message = auth_message(datagram)?;
        let status = if !self.nonces.redeem(&auth.snonce, from, now_ms) {
            Status::StaleNonce
        } else {
            match AUTH.check(&credential, &message, &auth.proof, from, now_ms) {
                Check::Limited => Status::RateLimited,
                Check::Wrong => Status::WrongPassword,
                Check::Ok(_) => {
                    let mut list = None;
                    let status = self.command(command, &auth, &credential, &current, &mut list, map, store, now_ms);
                    let status = status.await;
                    let n = result(out, opcode, id, me, status, list.as_ref())?;
                    // The answer, signed with the key the PC proved it knows (the old one
                    // after a password change).
                    let signature = remodaq_protocol::auth::server_signature(
                        &credential.server_key,
                        &[SERVER_LABEL, message[1], message[2], &out[..n]],
                    );
                    let end = n + KEY_LEN;
                    out.get_mut(n..end)?.copy_from_slice(&signature);
                    let effect = match (command, status) {
                        (Command::Restart, Status::Ok) => Effect::Restart,
                        _ => Effect::None,
                    };
                    return Some((end, effect));
                }
            }
        };
        result(out, opcode, id, me, status, None).map(|n| (n, Effect::None))
    }

    /// Carries out an authenticated command.
    #[allow(clippy::too_many_arguments)]
    async fn command<R: RawMutex, A: SettingsAccess, F: NorFlash>(
        &mut self,
        command: Command,
        auth: &Auth,
        credential: &Credential,
        current: &A::Settings,
        list: &mut Option<AllowList>,
        map: &Mutex<R, A>,
        store: &Store<F, A::Settings>,
        now_ms: u64,
    ) -> Status {
        match command {
            // Not on the console's port either (the web console's own check: web::settings).
            Command::SetNetwork(net) if net.is_valid() && net.port != current.http_port() => {
                let status = commit(map, store, |s| s.set_net(net)).await;
                if status == Status::Ok {
                    NETWORK_STORED.store(true, core::sync::atomic::Ordering::Relaxed);
                }
                status
            }
            Command::SetNetwork(_) => Status::Invalid,
            Command::Restart => Status::Ok,
            Command::GetAccess => {
                *list = Some(current.allow_list());
                Status::Ok
            }
            Command::SetAccess(_) if credential.is_factory() => Status::SetPasswordFirst,
            Command::SetAccess(new) => commit(map, store, |s| s.set_allow_list(new)).await,
            Command::SetPassword { public, sealed } => {
                let (secret, _) = self.agreement(now_ms);
                let shared = x25519(&secret, &public).await;
                // A seal made for any other key (a substituted one, an older one) does not open
                // (security review finding 8): refused, nothing committed.
                let Some(new) = open_credential(&shared, &[SEAL_LABEL, &auth.cnonce, &auth.snonce], &sealed) else {
                    remodaq_shared::warn!("discovery: a password sealed for another key, refused");
                    return Status::Invalid;
                };
                if !new.is_acceptable() || new.is_factory() {
                    return Status::Invalid;
                }
                let status = commit(map, store, |s| s.set_password(new)).await;
                if status == Status::Ok {
                    // A new key for the next change (what sealed this one is forgotten), once
                    // the change is stored: a change that failed can be sent again.
                    self.agreement = None;
                    remodaq_shared::diagnostics::DIAGNOSTICS.factory_password(false);
                    remodaq_shared::info!("discovery: password changed");
                }
                status
            }
        }
    }

    fn info<S: CommonSettings>(&self, id: u16, now_ms: u64, settings: &S, out: &mut [u8]) -> Option<usize> {
        let i = &self.identity;
        let mut w = Writer::new(out, op::INFO, id);
        w.bytes(&i.model.to_be_bytes()).bytes(&i.version.to_be_bytes()).bytes(&i.mac);
        w.net(&i.running).net(&settings.net());
        w.bytes(&((now_ms / 1000) as u32).to_be_bytes()).string(i.name.as_bytes());
        w.bytes(&[flags(settings)]).bytes(&fingerprint(&remodaq_shared::identity::update_key()));
        w.finish()
    }
}

/// The flags of INFO and CHALLENGE answers.
fn flags<S: CommonSettings>(settings: &S) -> u8 {
    let mut flags = 0;
    if !settings.allow_list().is_empty() {
        flags |= info_flags::WRITES_RESTRICTED;
    }
    if settings.password().is_factory() {
        flags |= info_flags::FACTORY_PASSWORD;
    }
    flags
}

/// Commits a change of the settings (the store's lock only).
async fn commit<R: RawMutex, A: SettingsAccess, F: NorFlash>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings),
) -> Status {
    match commit_change(map, store, change).await {
        Ok(()) => Status::Ok,
        Err(StoreError::Budget) => Status::CommitBudget,
        Err(_) => Status::StoreFailed,
    }
}

fn result(
    out: &mut [u8],
    opcode: u8,
    id: u16,
    mac: [u8; 6],
    status: Status,
    list: Option<&AllowList>,
) -> Option<usize> {
    let mut w = Writer::new(out, opcode | op::REPLY, id);
    w.bytes(&mac).bytes(&[status as u8]);
    if let Some(list) = list {
        w.allow_list(list);
    }
    w.finish()
}

/// A UDP socket as the service needs it (embassy-net on the target, std on the host).
#[allow(async_fn_in_trait)]
pub trait Datagrams {
    /// A socket error.
    type Error: remodaq_shared::fmt::Loggable;
    /// Receives one datagram: its length, source address and port. A datagram longer than the
    /// buffer may be truncated; the buffer is one byte longer than [`MAX_DATAGRAM`], so the
    /// decoder still sees that it is oversized.
    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), Self::Error>;
    /// Sends one datagram.
    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), Self::Error>;
}

/// Requests from outside the module's subnet (answered by broadcast) served at once...
pub const BROADCAST_BURST: u32 = 8;
/// ...and one more every this many ms. A forged off-subnet request makes every module on the
/// LAN broadcast its answer, to a port the sender chose (security review finding 12): bounded,
/// so that a flood of them cannot turn the modules into an amplifier. An administrator on
/// another subnet (a search, then a challenge and a command per change: about three requests)
/// never meets it.
pub const BROADCAST_REFILL_MS: u64 = 500;

/// Serves the protocol forever. Replies go to the requester, or to the broadcast address (same
/// port) when the requester is outside the module's subnet, so a PC can configure a module
/// whose settings do not fit its network; such requests draw on a budget
/// ([`BROADCAST_BURST`], [`BROADCAST_REFILL_MS`]), and one beyond it is dropped unread (no
/// effect without its answer). `effect` runs after each reply is sent.
pub async fn serve<R, A, F, D>(
    socket: &mut D,
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    identity: Identity,
    mut effect: impl AsyncFnMut(Effect),
) -> !
where
    R: RawMutex,
    A: SettingsAccess,
    F: NorFlash,
    D: Datagrams,
{
    let mut service = Service::new(identity);
    // The first login's key made ahead, off the main executor (the board has seeded the
    // module's random numbers by now).
    remodaq_shared::offload::prepare_key_pair();
    let mut broadcasts = Budget::new(BROADCAST_BURST, BROADCAST_REFILL_MS);
    let mut rx = [0u8; MAX_DATAGRAM + 1];
    let mut tx = [0u8; MAX_DATAGRAM];
    loop {
        let (n, ip, port) = match socket.recv(&mut rx).await {
            Ok(received) => received,
            Err(e) => {
                remodaq_shared::warn!("discovery: receive failed: {:?}", e);
                continue;
            }
        };
        let now_ms = embassy_time::Instant::now().as_millis();
        let near = identity.running.same_subnet(ip);
        if !near && !broadcasts.take(now_ms) {
            remodaq_shared::debug!("discovery: broadcast budget spent: a request from another subnet dropped");
            continue;
        }
        let reply = service.handle(&rx[..n], ip, now_ms, map, store, &mut tx).await;
        let Some((len, what)) = reply else { continue };
        let to = if near { ip } else { [255; 4] };
        if let Err(e) = socket.send(&tx[..len], to, port).await {
            remodaq_shared::warn!("discovery: send failed: {:?}", e);
        }
        effect(what).await;
    }
}
