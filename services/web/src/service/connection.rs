//! A connection's entry ([`serve_connection`], which every board's connection task calls):
//! the connections served at once, their buffer, timeouts and longest time, and the console's
//! pages.

use core::cell::Cell;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::io::Socket;
use picoserve::{Config, EmbassyRuntime, Router, Timeouts};
use remodaq_shared::identity::Identity;
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::module::{SettingsAccess, Store};

use super::api::{Api, SESSIONS};

/// HTTP connections served at once (issue #25: at most 2, each in a task of its own, never a
/// Modbus slot).
pub const CONNECTIONS: usize = remodaq_shared::sockets::WEB_CONNECTIONS;

/// The request head and body together must fit (a larger head: 431 and closed; a larger
/// body: 413). A login is about 300 bytes of head and 150 of body.
pub const HTTP_BUFFER: usize = 1536;

/// The timeouts of every connection: the first byte within 5 s, the whole request within 3 s
/// of it, each write within 1 s; one request per connection (no keep-alive: a connection
/// slot is not held between a page's requests).
pub static CONFIG: Config = Config::new(Timeouts {
    start_read_request: embassy_time::Duration::from_secs(5),
    persistent_start_read_request: embassy_time::Duration::from_secs(1),
    read_request: embassy_time::Duration::from_secs(3),
    write: embassy_time::Duration::from_secs(1),
})
.close_connection_after_response();

/// Milliseconds since the module started.
fn now_ms() -> u64 {
    embassy_time::Instant::now().as_millis()
}

/// picoserve's [`picoserve::io::Write::write_with`] for a writer that has no buffer of its own
/// to lend (a std socket, a test's output): `f` formats into a 1 KiB buffer, which is then
/// written whole.
pub async fn write_with_buffer<W: embedded_io_async::Write, F: FnOnce(picoserve::mem::BorrowedCursor<'_>) -> T, T>(
    writer: &mut W,
    f: F,
) -> Result<T, W::Error> {
    let mut buffer = [0u8; 1024];
    let mut buffer = picoserve::mem::BorrowedBuffer::new(&mut buffer);
    let output = f(buffer.unfilled());
    writer.write_all(buffer.filled()).await.map(|()| output)
}

/// How a connection ended.
pub struct Served<E: embedded_io_async::Error> {
    /// A signed restart request of this connection was answered: restart now (the connection
    /// is closed; the other connection's requests never set this).
    pub restart: bool,
    /// The connection's end: an error or a timeout of picoserve's.
    pub result: Result<(), picoserve::Error<E>>,
}

/// Serves one connection (`socket`, from the client at `peer`) with the module's API, in
/// `buffer`; every board's connection task calls this.
pub async fn serve_connection<R: RawMutex, M: RegisterMap + SettingsAccess, F: NorFlash, S: Socket<EmbassyRuntime>>(
    map: &Mutex<R, M>,
    store: &Store<F, M::Settings>,
    identity: Identity,
    peer: [u8; 4],
    socket: S,
    buffer: &mut [u8; HTTP_BUFFER],
) -> Served<S::Error> {
    let restart = Cell::new(false);
    let api = Api { map, store, identity, sessions: &SESSIONS, peer, now_ms, restart: &restart };
    let app = Router::from_service(api);
    // Pinned where it is made: the timeout below takes a pointer to it, not the future itself
    // (moving a future copies its whole size through the stack: issue #39, the stack).
    let serve =
        core::pin::pin!(picoserve::Server::custom(&app, picoserve::time::EmbassyTimer, &CONFIG, buffer).serve(socket));
    // picoserve's timeouts bound each read and write, not a client that reads its answer a byte
    // at a time: the whole connection is bounded too (dropping it closes the socket), never in
    // the middle of a settings commit.
    let result = match embassy_futures::select::select(serve, deadline(CONNECTION_MAX)).await {
        embassy_futures::select::Either::First(served) => served.map(|_| ()),
        embassy_futures::select::Either::Second(()) => Ok(()),
    };
    Served { restart: restart.get(), result }
}

/// `max` from now, and then the end of any settings commit under way
/// ([`remodaq_shared::module::commit_under_way`]): a connection dropped at its deadline is
/// never dropped between a commit's flash write and the register map's update (security review
/// finding 15c). Polled only while the connection's future waits, so a commit it is in the
/// middle of is under way when this looks.
pub async fn deadline(max: embassy_time::Duration) {
    embassy_time::Timer::after(max).await;
    while remodaq_shared::module::commit_under_way() {
        embassy_time::Timer::after(COMMIT_POLL).await;
    }
}

/// How often a connection past its deadline looks whether the commit under way has ended.
const COMMIT_POLL: embassy_time::Duration = embassy_time::Duration::from_millis(20);

/// The longest a connection is served: one request (5 s to start, 3 s to arrive), its answer,
/// and the close.
pub const CONNECTION_MAX: embassy_time::Duration = embassy_time::Duration::from_secs(10);

/// The console's pages: path, type, and the file gzip-compressed at build time (build.rs).
pub(super) const PAGES: [(&str, &str, &[u8]); 4] = [
    ("/", "text/html; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/index.html.gz"))),
    ("/app.js", "text/javascript; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/app.js.gz"))),
    ("/auth.js", "text/javascript; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/auth.js.gz"))),
    ("/style.css", "text/css; charset=utf-8", include_bytes!(concat!(env!("OUT_DIR"), "/style.css.gz"))),
];
