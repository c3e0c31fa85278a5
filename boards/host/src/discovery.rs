//! The discovery / configuration service of the simulated module on a std UDP socket. Restart
//! re-executes the process with the same arguments (new network settings then apply: the
//! Modbus port when `--listen` gives no port); identify is logged (there is no LED).

use std::net::{SocketAddr, SocketAddrV4, UdpSocket};

use async_io::Async;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_shared::board::{Effects, Shared};
use remodaq_shared::discovery::{serve, Datagrams, Effect, Identity};
use remodaq_shared::module::{SettingsAccess, Store};

/// The service's socket.
pub struct HostDatagrams(Async<UdpSocket>);

impl HostDatagrams {
    /// Binds the socket (broadcast allowed) and logs where.
    pub fn bind(addr: SocketAddr) -> std::io::Result<Self> {
        let socket = Async::<UdpSocket>::bind(addr)?;
        socket.get_ref().set_broadcast(true)?;
        log::info!("discovery: listening on {}", socket.get_ref().local_addr()?);
        Ok(Self(socket))
    }
}

impl Datagrams for &HostDatagrams {
    type Error = std::io::ErrorKind;

    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), Self::Error> {
        match self.0.recv_from(buf).await.map_err(|e| e.kind())? {
            (n, SocketAddr::V4(from)) => Ok((n, from.ip().octets(), from.port())),
            (_, SocketAddr::V6(_)) => Err(std::io::ErrorKind::Unsupported),
        }
    }

    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), Self::Error> {
        self.0.send_to(buf, SocketAddrV4::new(ip.into(), port)).await.map(|_| ()).map_err(|e| e.kind())
    }
}

/// The simulated module's identify (a log line: there is no LED) and restart (the same
/// program with the same arguments).
pub struct HostEffects;

impl Effects for HostEffects {
    async fn apply(&self, effect: Effect) {
        match effect {
            Effect::None => {}
            Effect::Identify => log::info!("identify: the module's LED would blink for 10 s"),
            Effect::Restart => restart(),
        }
    }
}

/// Serves the protocol forever.
pub async fn run<A: SettingsAccess, F: NorFlash>(
    socket: &HostDatagrams,
    map: &Shared<A>,
    store: &Store<F, A::Settings>,
    identity: Identity,
    effects: &impl Effects,
) -> ! {
    let mut socket = socket;
    serve(&mut socket, map, store, identity, async |effect| effects.apply(effect).await).await
}

/// Set in the environment of a simulated module started by a restart (its reset cause).
pub const RESTARTED: &str = "REMODAQ_RESTARTED";

/// Restarts the simulated module: the same program with the same arguments.
fn restart() {
    log::info!("restart requested: restarting");
    let args: Vec<String> = std::env::args().collect();
    let Ok(exe) = std::env::current_exe() else {
        log::error!("restart: cannot find the program");
        return;
    };
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        let e = std::process::Command::new(exe).args(&args[1..]).env(RESTARTED, "1").exec();
        log::error!("restart failed: {e}");
    }
    #[cfg(not(unix))]
    {
        match std::process::Command::new(exe).args(&args[1..]).env(RESTARTED, "1").spawn() {
            Ok(_) => std::process::exit(0),
            Err(e) => log::error!("restart failed: {e}"),
        }
    }
}
