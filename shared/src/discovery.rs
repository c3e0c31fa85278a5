//! The module side of the discovery and configuration protocol: [`Service::handle`] turns one
//! datagram into at most one reply and an effect for the board; [`serve`] runs it on a socket.
//! The codec is `remodaq_protocol::discovery` (re-exported here).

pub use remodaq_protocol::discovery::*;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;

use crate::access::AllowList;
use crate::module::{commit_change, CommonSettings, SettingsAccess, Store};
use crate::net::NetConfig;
use crate::password::{self, Check, Limiter, PasswordHash};

/// What a module says about itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    /// Module name register value (8318h, 8350h).
    pub model: u16,
    /// Model string.
    pub name: &'static str,
    /// Firmware version register value.
    pub version: u16,
    /// MAC address.
    pub mac: [u8; 6],
    /// The network settings in force since start-up.
    pub running: NetConfig,
}

/// What the board must do after sending the reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    /// Nothing.
    None,
    /// Restart the module (new network settings take effect).
    Restart,
    /// Blink the identify LED for 10 s.
    Identify,
}

/// The module side of the protocol.
pub struct Service {
    identity: Identity,
    limiter: Limiter,
}

impl Service {
    /// The service of a module.
    pub fn new(identity: Identity) -> Self {
        Self { identity, limiter: Limiter::default() }
    }

    /// Handles one datagram from `from` at `now_ms` (ms since start): the reply's length in
    /// `out` (none for datagrams that are ignored or addressed to another module) and the
    /// effect to carry out after sending it. The map is locked only to copy the settings in
    /// force: the password is hashed, and new settings committed, without its lock.
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
        let (mac, password) = match request {
            Request::Search => return self.info(id, now_ms, &current, out).map(|n| (n, Effect::None)),
            Request::Identify { mac } if mac == me => {
                return result(out, op::IDENTIFY, id, me, Status::Ok, None).map(|n| (n, Effect::Identify));
            }
            Request::Identify { .. } => return None,
            Request::SetNetwork { mac, password, .. }
            | Request::Restart { mac, password }
            | Request::SetPassword { mac, password, .. }
            | Request::GetAccess { mac, password }
            | Request::SetAccess { mac, password, .. } => (mac, password),
        };
        if mac != me {
            return None;
        }
        let opcode = request.opcode();
        let mut list = None;
        let status = match self.limiter.check(&current.password(), password, from, now_ms) {
            Check::Locked => Status::RateLimited,
            Check::Wrong => Status::WrongPassword,
            Check::Ok => match request {
                Request::SetNetwork { net, .. } if net.is_valid() => commit(map, store, |s| s.set_net(net)).await,
                Request::SetPassword { new, .. } if (password::MIN_LEN..=password::MAX_LEN).contains(&new.len()) => {
                    let hash = PasswordHash::new(current.password().next_salt(&me, now_ms), new);
                    commit(map, store, |s| s.set_password(hash)).await
                }
                Request::SetAccess { list, .. } => commit(map, store, |s| s.set_allow_list(list)).await,
                Request::GetAccess { .. } => {
                    list = Some(current.allow_list());
                    Status::Ok
                }
                Request::Restart { .. } => Status::Ok,
                _ => Status::Invalid,
            },
        };
        let effect = if opcode == op::RESTART && status == Status::Ok { Effect::Restart } else { Effect::None };
        if status == Status::WrongPassword {
            crate::warn!("discovery: wrong configuration password");
        }
        result(out, opcode, id, me, status, list.as_ref()).map(|n| (n, effect))
    }

    fn info<S: CommonSettings>(&self, id: u16, now_ms: u64, settings: &S, out: &mut [u8]) -> Option<usize> {
        let i = &self.identity;
        let mut w = Writer::new(out, op::INFO, id);
        w.bytes(&i.model.to_be_bytes()).bytes(&i.version.to_be_bytes()).bytes(&i.mac);
        w.net(&i.running).net(&settings.net());
        w.bytes(&((now_ms / 1000) as u32).to_be_bytes()).string(i.name.as_bytes());
        let restricted = !settings.allow_list().is_empty();
        w.bytes(&[if restricted { info_flags::WRITES_RESTRICTED } else { 0 }]);
        w.finish()
    }
}

/// Commits a change of the settings (the store's lock only).
async fn commit<R: RawMutex, A: SettingsAccess, F: NorFlash>(
    map: &Mutex<R, A>,
    store: &Store<F, A::Settings>,
    change: impl FnOnce(&mut A::Settings),
) -> Status {
    match commit_change(map, store, change).await {
        Ok(()) => Status::Ok,
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
    type Error: crate::fmt::Loggable;
    /// Receives one datagram: its length, source address and port. A datagram longer than the
    /// buffer may be truncated; the buffer is one byte longer than [`MAX_DATAGRAM`], so the
    /// decoder still sees that it is oversized.
    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), Self::Error>;
    /// Sends one datagram.
    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), Self::Error>;
}

/// Serves the protocol forever. Replies go to the requester, or to the broadcast address (same
/// port) when the requester is outside the module's subnet, so a PC can configure a module
/// whose settings do not fit its network. `effect` runs after each reply is sent.
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
    let mut rx = [0u8; MAX_DATAGRAM + 1];
    let mut tx = [0u8; MAX_DATAGRAM];
    loop {
        let (n, ip, port) = match socket.recv(&mut rx).await {
            Ok(received) => received,
            Err(e) => {
                crate::warn!("discovery: receive failed: {:?}", e);
                continue;
            }
        };
        let now_ms = embassy_time::Instant::now().as_millis();
        let reply = service.handle(&rx[..n], ip, now_ms, map, store, &mut tx).await;
        let Some((len, what)) = reply else { continue };
        let to = if identity.running.same_subnet(ip) { ip } else { [255; 4] };
        if let Err(e) = socket.send(&tx[..len], to, port).await {
            crate::warn!("discovery: send failed: {:?}", e);
        }
        effect(what).await;
    }
}
