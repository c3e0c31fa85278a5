//! The web console of the simulated module (`--http ADDR:PORT`, docs/web.md): the shared
//! picoserve service on std sockets, at most [`CONNECTIONS`] at a time (each task serves one
//! connection), apart from the Modbus connections; the buffer, timeouts and sessions are the
//! module's ([`remodaq_web::service`]).

use std::net::{TcpListener, TcpStream};

use async_io::Async;
use embedded_io_adapters::futures_03::FromFutures;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::io::Socket;
use picoserve::Timeouts;
use remodaq_shared::board::Shared;
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};
pub use remodaq_web::service::CONNECTIONS;
use remodaq_web::service::{serve_connection, HTTP_BUFFER};

use crate::modbus::{accept, ipv4};

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
        remodaq_web::service::write_with_buffer(&mut self.0, f).await
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

/// One of the web tasks: accept, serve the connection, repeat.
/// Returns when a signed request asked for a restart (its answer sent, its connection closed).
pub async fn connection_task<M: RegisterMap + SettingsAccess, F: NorFlash>(
    listener: &Listener,
    map: &Shared<M>,
    store: &Store<F, M::Settings>,
    identity: Identity,
) {
    let mut buffer = [0u8; HTTP_BUFFER];
    // The host build serves where its command line says, not at the stored port.
    if let Ok(addr) = listener.get_ref().local_addr() {
        remodaq_web::settings::serving_on(addr.port());
    }
    loop {
        let (stream, peer) = accept(listener, "web").await;
        let served = serve_connection(map, store, identity, ipv4(peer.ip()), Connection(stream), &mut buffer).await;
        if let Err(e) = served.result {
            log::debug!("web: {peer}: {e:?}");
        }
        if served.restart {
            return;
        }
    }
}
