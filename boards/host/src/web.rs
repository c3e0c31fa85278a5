//! The web console of the simulated module (`--http ADDR:PORT`, docs/web.md): the shared
//! picoserve service on std sockets, at most [`CONNECTIONS`] at a time (each task serves one
//! connection), apart from the Modbus connections.

use core::cell::RefCell;
use std::net::{TcpListener, TcpStream};

use async_io::Async;
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embedded_io_adapters::futures_03::FromFutures;
use picoserve::io::Socket;
use picoserve::{Config, Router, Timeouts};
use remodaq_shared::board::Shared;
use remodaq_shared::discovery::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::SettingsAccess;
use remodaq_shared::web::service::{Api, SharedSessions};
use remodaq_shared::web::Sessions;

use crate::modbus::{accept, ipv4};

/// HTTP connections served at once (issue #25: at most 2, never a Modbus slot).
pub const CONNECTIONS: usize = 2;

/// The request head and body together must fit (a larger head: 431 and closed; a larger
/// body: 413).
pub const HTTP_BUFFER: usize = 2048;

/// The timeouts of every connection: the first byte within 5 s, the whole request within 3 s
/// of it, each write within 1 s; one request per connection.
pub static CONFIG: Config = Config::new(Timeouts {
    start_read_request: embassy_time::Duration::from_secs(5),
    persistent_start_read_request: embassy_time::Duration::from_secs(1),
    read_request: embassy_time::Duration::from_secs(3),
    write: embassy_time::Duration::from_secs(1),
})
.close_connection_after_response();

/// The web sessions of this module.
static SESSIONS: SharedSessions = Blocking::new(RefCell::new(Sessions::new()));

/// The web listener.
pub type Listener = Async<TcpListener>;

/// Binds the web listener.
pub fn bind(addr: std::net::SocketAddr) -> std::io::Result<Listener> {
    Async::<TcpListener>::bind(addr)
}

/// A connection, for picoserve.
struct Connection(Async<TcpStream>);

/// The sending half: picoserve formats into a buffer it borrows ([`picoserve::io::Write`]).
struct Sender<'a>(FromFutures<&'a Async<TcpStream>>);

impl embedded_io_async::ErrorType for Sender<'_> {
    type Error = std::io::Error;
}

impl embedded_io_async::Write for Sender<'_> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.write(buf).await
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        self.0.flush().await
    }
}

impl picoserve::io::Write for Sender<'_> {
    async fn write_with<F: FnOnce(picoserve::mem::BorrowedCursor<'_>) -> R, R>(
        &mut self,
        f: F,
    ) -> Result<R, Self::Error> {
        let mut buffer = [0u8; 1024];
        let mut buffer = picoserve::mem::BorrowedBuffer::new(&mut buffer);
        let output = f(buffer.unfilled());
        embedded_io_async::Write::write_all(&mut self.0, buffer.filled()).await.map(|()| output)
    }
}

impl Socket<picoserve::EmbassyRuntime> for Connection {
    type Error = std::io::Error;
    type ReadHalf<'a> = FromFutures<&'a Async<TcpStream>>;
    type WriteHalf<'a> = Sender<'a>;

    fn split(&mut self) -> (Self::ReadHalf<'_>, Self::WriteHalf<'_>) {
        (FromFutures::new(&self.0), Sender(FromFutures::new(&self.0)))
    }

    async fn abort<T: picoserve::time::Timer<picoserve::EmbassyRuntime>>(
        self,
        _: &Timeouts,
        _: &T,
    ) -> Result<(), picoserve::Error<Self::Error>> {
        let _ = self.0.get_ref().shutdown(std::net::Shutdown::Both);
        Ok(())
    }

    async fn shutdown<T: picoserve::time::Timer<picoserve::EmbassyRuntime>>(
        self,
        _: &Timeouts,
        _: &T,
    ) -> Result<(), picoserve::Error<Self::Error>> {
        let _ = self.0.get_ref().shutdown(std::net::Shutdown::Write);
        Ok(())
    }
}

/// Milliseconds since the module started.
fn now_ms() -> u64 {
    embassy_time::Instant::now().as_millis()
}

/// One of the web tasks: accept, serve the connection, repeat.
pub async fn connection_task<M: RegisterMap + SettingsAccess>(
    listener: &Listener,
    map: &Shared<M>,
    identity: Identity,
) -> ! {
    let mut buffer = [0u8; HTTP_BUFFER];
    loop {
        let (stream, peer) = accept(listener, "web").await;
        let api = Api { map, identity, sessions: &SESSIONS, peer: ipv4(peer.ip()), now_ms };
        let app = Router::from_service(api);
        let served = picoserve::Server::custom(&app, picoserve::time::EmbassyTimer, &CONFIG, &mut buffer)
            .serve(Connection(stream))
            .await;
        if let Err(e) = served {
            log::debug!("web: {peer}: {e:?}");
        }
    }
}
