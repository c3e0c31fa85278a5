//! The discovery / configuration service of the simulated module on a std UDP socket. Restart
//! re-executes the process with the same arguments (new network settings then apply: the
//! Modbus port when `--listen` gives no port); identify is logged (there is no LED).

use std::net::{SocketAddr, SocketAddrV4, UdpSocket};

use async_io::Async;
use embedded_storage_async::nor_flash::NorFlash;
use remodaq_discovery::{serve, Datagrams, Effect, Identity};
use remodaq_shared::board::{Effects, Shared};
use remodaq_shared::module::{SettingsAccess, Store};

/// The service's socket, and the interface the last request came in on (Linux).
pub struct HostDatagrams {
    socket: Async<UdpSocket>,
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    interface: std::cell::Cell<Option<u32>>,
}

impl HostDatagrams {
    /// Binds the socket (broadcast allowed; on Linux, told which interface each datagram came
    /// in on) and logs where.
    pub fn bind(addr: SocketAddr) -> std::io::Result<Self> {
        let socket = Async::<UdpSocket>::bind(addr)?;
        socket.get_ref().set_broadcast(true)?;
        #[cfg(target_os = "linux")]
        nix::sys::socket::setsockopt(socket.get_ref(), nix::sys::socket::sockopt::Ipv4PacketInfo, &true)?;
        log::info!("discovery: listening on {}", socket.get_ref().local_addr()?);
        Ok(Self { socket, interface: std::cell::Cell::new(None) })
    }
}

/// A reply leaves by the interface its request came in on, with no route needed, as the module
/// answers out of its only interface: a module whose settings do not fit the PC's network
/// (factory 192.168.0.1/24, no gateway) answers a PC on another subnet by broadcast on that
/// interface (docs/discovery.md). On Linux through IP_PKTINFO (ip(7)); elsewhere by the
/// host's routes.
#[cfg(target_os = "linux")]
mod by_interface {
    use std::io::{IoSlice, IoSliceMut};
    use std::os::fd::AsRawFd;

    use nix::sys::socket::{recvmsg, sendmsg, ControlMessage, ControlMessageOwned, MsgFlags, SockaddrIn};

    /// One datagram: its length, sender, and the index of the interface it came in on.
    pub fn recv(socket: &std::net::UdpSocket, buf: &mut [u8]) -> std::io::Result<(usize, SockaddrIn, Option<u32>)> {
        let mut iov = [IoSliceMut::new(buf)];
        let mut space = nix::cmsg_space!(nix::libc::in_pktinfo);
        let msg = recvmsg::<SockaddrIn>(socket.as_raw_fd(), &mut iov, Some(&mut space), MsgFlags::empty())?;
        let interface = msg.cmsgs()?.find_map(|c| match c {
            ControlMessageOwned::Ipv4PacketInfo(info) => u32::try_from(info.ipi_ifindex).ok(),
            _ => None,
        });
        let from = msg.address.ok_or(std::io::ErrorKind::InvalidData)?;
        Ok((msg.bytes, from, interface))
    }

    /// Sends `buf` to `to` out of `interface`.
    pub fn send(socket: &std::net::UdpSocket, buf: &[u8], to: SockaddrIn, interface: u32) -> std::io::Result<()> {
        let info = nix::libc::in_pktinfo {
            ipi_ifindex: interface as _,
            ipi_spec_dst: nix::libc::in_addr { s_addr: 0 },
            ipi_addr: nix::libc::in_addr { s_addr: 0 },
        };
        sendmsg(
            socket.as_raw_fd(),
            &[IoSlice::new(buf)],
            &[ControlMessage::Ipv4PacketInfo(&info)],
            MsgFlags::empty(),
            Some(&to),
        )?;
        Ok(())
    }
}

impl Datagrams for &HostDatagrams {
    type Error = std::io::ErrorKind;

    async fn recv(&mut self, buf: &mut [u8]) -> Result<(usize, [u8; 4], u16), Self::Error> {
        #[cfg(target_os = "linux")]
        {
            let (n, from, interface) =
                self.socket.read_with(|s| by_interface::recv(s, buf)).await.map_err(|e| e.kind())?;
            self.interface.set(interface);
            Ok((n, from.ip().octets(), from.port()))
        }
        #[cfg(not(target_os = "linux"))]
        match self.socket.recv_from(buf).await.map_err(|e| e.kind())? {
            (n, SocketAddr::V4(from)) => Ok((n, from.ip().octets(), from.port())),
            (_, SocketAddr::V6(_)) => Err(std::io::ErrorKind::Unsupported),
        }
    }

    async fn send(&mut self, buf: &[u8], ip: [u8; 4], port: u16) -> Result<(), Self::Error> {
        let to = SocketAddrV4::new(ip.into(), port);
        #[cfg(target_os = "linux")]
        if let Some(interface) = self.interface.get() {
            return self
                .socket
                .write_with(|s| by_interface::send(s, buf, to.into(), interface))
                .await
                .map_err(|e| e.kind());
        }
        self.socket.send_to(buf, to).await.map(|_| ()).map_err(|e| e.kind())
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

/// Set in the environment of a simulated module started by a restart: the flash commit
/// budgets' debts (`remodaq_shared::settings::Retained`), four words separated by commas.
pub const RETAINED: &str = "REMODAQ_RETAINED";

/// Restarts the simulated module: the same program with the same arguments.
fn restart() {
    log::info!("restart requested: restarting");
    let args: Vec<String> = std::env::args().collect();
    let retained = remodaq_shared::settings::Retained::now().to_words().map(|w| w.to_string()).join(",");
    let Ok(exe) = std::env::current_exe() else {
        log::error!("restart: cannot find the program");
        return;
    };
    #[cfg(unix)]
    {
        use std::os::unix::process::CommandExt;
        let e = std::process::Command::new(exe).args(&args[1..]).env(RESTARTED, "1").env(RETAINED, &retained).exec();
        log::error!("restart failed: {e}");
    }
    #[cfg(not(unix))]
    {
        match std::process::Command::new(exe).args(&args[1..]).env(RESTARTED, "1").env(RETAINED, &retained).spawn() {
            Ok(_) => std::process::exit(0),
            Err(e) => log::error!("restart failed: {e}"),
        }
    }
}
