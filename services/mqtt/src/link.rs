//! MQTT off the main executor (the STM32 and QEMU boards; docs/mqtt.md, "Never in the way"):
//! the whole service ([`crate::service::run`]: the points read and their payloads formatted,
//! minimq's session, TLS's handshake and records) runs in a task of the board's background
//! executor, in thread mode, which every other task preempts, so that a Modbus request never
//! waits for any of it. The main executor keeps only the TCP socket (embassy-net's stack is not
//! to be touched from two priorities): [`carry`] opens and closes it as the service asks and moves
//! its bytes between it and two pipes, which the service reads and writes through a [`Link`].
//!
//! The two sides share nothing but what is here, behind critical sections: the pipes, the
//! link's state (which carries the service's requests) and two signals.
//!
//! ```text
//!  main executor                          | background executor (thread mode)
//!  socket --carry--> FROM_BROKER ------------> Link::read  --> the session (TLS under it, or not)
//!  socket <--carry-- TO_BROKER <-------------- Link::write <-- the session
//! ```

use core::cell::Cell;

use embassy_futures::select::{select, select3, Either};
use embassy_net::tcp::TcpSocket;
use embassy_net::{IpEndpoint, Ipv4Address};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex as Cs;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use embedded_io_async::{ErrorKind, ErrorType, Read, Write};
use remodaq_net::reset;
use remodaq_shared::warn;

/// The broker's bytes on their way to the service, and the service's to the socket: a few
/// publications (or TLS records) in flight in each direction.
const PIPE: usize = 1024;
/// The service's bytes wait in their pipe this long (or until it is half full) before they go
/// to the socket together: a look's publications leave in a few segments instead of one each,
/// and the network's runner handles that many fewer frames, each of which a Modbus request
/// arriving with it waits for (issue #40, docs/mqtt.md "Never in the way").
const GATHER: Duration = Duration::from_millis(2);

/// The broker's bytes, from the socket to the service.
static FROM_BROKER: Pipe<Cs, PIPE> = Pipe::new();
/// The service's bytes, from the service to the socket.
static TO_BROKER: Pipe<Cs, PIPE> = Pipe::new();

/// Where the link is, and what the service asks of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// No connection (the socket closed or reset).
    Idle,
    /// The service asks for a connection to this address and port.
    Connecting([u8; 4], u16),
    /// Connected: the bytes are carried.
    Open,
    /// The connection could not be made, or it ended (the broker closed it, the socket failed or
    /// timed out): what the broker sent before stays readable.
    Ended,
    /// The service asks for the connection's end, closed in order (the broker gives the will at
    /// once).
    Closing,
}

static STATE: Mutex<Cs, Cell<State>> = Mutex::new(Cell::new(State::Idle));
/// Wakes [`carry`]: a request, or the service took from or put into a pipe.
static TO_MAIN: Signal<Cs, ()> = Signal::new();
/// Wakes the service: the state changed, or [`carry`] emptied some of [`TO_BROKER`].
static TO_SERVICE: Signal<Cs, ()> = Signal::new();

fn state() -> State {
    STATE.lock(Cell::get)
}

/// The service's request (it may replace any state): `carry` is woken to act on it.
fn ask(request: State) {
    STATE.lock(|s| s.set(request));
    TO_MAIN.signal(());
}

/// `carry`'s move from `from` to `to`, unless the service asked for something else meanwhile;
/// the service is woken either way.
fn advance(from: State, to: State) {
    STATE.lock(|s| {
        if s.get() == from {
            s.set(to);
        }
    });
    TO_SERVICE.signal(());
}

/// The main executor's side: opens the connections the service asks for on `socket`, carries
/// their bytes and closes them, for ever. `timeout`: a broker silent this long ends the
/// connection.
pub async fn carry(socket: &mut TcpSocket<'_>, timeout: Duration) -> ! {
    loop {
        let (broker, port) = match state() {
            State::Connecting(broker, port) => (broker, port),
            State::Closing => {
                // What the service wrote last, gathering still, goes first.
                if !TO_BROKER.is_empty() && socket.can_send() {
                    let _ = socket
                        .write_with(|b| {
                            let n = TO_BROKER.try_read(b).unwrap_or(0);
                            (n, n)
                        })
                        .await;
                }
                remodaq_net::close(socket).await;
                advance(State::Closing, State::Idle);
                continue;
            }
            State::Idle | State::Open | State::Ended => {
                TO_MAIN.wait().await;
                continue;
            }
        };
        let asked = State::Connecting(broker, port);
        // The last connection, if it broke without the socket knowing; nothing of it stays.
        reset(socket).await;
        FROM_BROKER.clear();
        TO_BROKER.clear();
        socket.set_timeout(Some(timeout));
        let [a, b, c, d] = broker;
        let connecting = socket.connect(IpEndpoint::new(Ipv4Address::new(a, b, c, d).into(), port));
        match select(connecting, changed(asked)).await {
            Either::First(Ok(())) => advance(asked, State::Open),
            Either::First(Err(e)) => {
                warn!("mqtt: connect: {:?}", e);
                advance(asked, State::Ended);
            }
            // Asked for something else: the next round does it.
            Either::Second(()) => continue,
        }
        pump(socket).await;
    }
}

/// Until the state is no longer `now`.
async fn changed(now: State) {
    while state() == now {
        TO_MAIN.wait().await;
    }
}

/// Moves the bytes between `socket` and the pipes while the link is open; at the socket's end,
/// the link has [`State::Ended`].
async fn pump(socket: &mut TcpSocket<'_>) {
    // When the service's bytes waiting began to.
    let mut waiting: Option<Instant> = None;
    loop {
        if state() != State::Open {
            return;
        }
        let due = match (TO_BROKER.is_empty(), waiting) {
            (true, _) => {
                waiting = None;
                false
            }
            (false, None) => {
                waiting = Some(Instant::now());
                TO_BROKER.len() >= PIPE / 2
            }
            (false, Some(since)) => TO_BROKER.len() >= PIPE / 2 || since.elapsed() >= GATHER,
        };
        // What can move now moves: the closures run at once (the socket can take or give), so
        // nothing is held between a pipe and the socket when this is dropped.
        if due && socket.can_send() {
            let sent = socket.write_with(|b| {
                let n = TO_BROKER.try_read(b).unwrap_or(0);
                (n, n)
            });
            if sent.await.is_err() {
                break;
            }
            // Room again: a write may be waiting for it.
            TO_SERVICE.signal(());
            waiting = None;
            continue;
        }
        if socket.can_recv() && !FROM_BROKER.is_full() {
            // The pipe wakes its reader.
            let received = socket.read_with(|b| {
                let n = FROM_BROKER.try_write(b).unwrap_or(0);
                (n, n)
            });
            if received.await.is_err() {
                break;
            }
            continue;
        }
        if !socket.may_recv() {
            break;
        }
        // Then wait for the socket or the service.
        let readable = async {
            if FROM_BROKER.is_full() {
                core::future::pending::<()>().await;
            }
            socket.wait_read_ready().await;
        };
        let writable = async {
            match waiting {
                None => core::future::pending::<()>().await,
                // Gathered long enough (or the pipe half full: `TO_MAIN` says so).
                Some(since) if !due => Timer::at(since + GATHER).await,
                Some(_) => {}
            }
            socket.wait_write_ready().await;
        };
        select3(readable, writable, TO_MAIN.wait()).await;
    }
    advance(State::Open, State::Ended);
}

/// The service's side: a connection to `broker`:`port`, once `carry` made it (`None`: it could
/// not, logged there).
pub async fn connect(broker: [u8; 4], port: u16) -> Option<Link> {
    ask(State::Connecting(broker, port));
    loop {
        match state() {
            State::Open => return Some(Link),
            State::Connecting(..) => TO_SERVICE.wait().await,
            State::Idle | State::Ended | State::Closing => return None,
        }
    }
}

/// The service's side: closes the connection, if any, in order (waits until it did).
pub async fn close() {
    if state() == State::Idle {
        return;
    }
    ask(State::Closing);
    while state() != State::Idle {
        TO_SERVICE.wait().await;
    }
}

/// The service's end of an open connection ([`connect`]): the broker's bytes through the pipes.
/// Once the connection ended, what the broker sent before is read, then an error.
pub struct Link;

impl ErrorType for Link {
    type Error = ErrorKind;
}

impl Read for Link {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            // What the broker sent before the end is read first.
            if state() != State::Open && FROM_BROKER.is_empty() {
                return Err(ErrorKind::ConnectionReset);
            }
            // A pipe's read is cancel-safe: dropped, it took nothing.
            if let Either::First(n) = select(FROM_BROKER.read(buf), TO_SERVICE.wait()).await {
                // Room again for what the socket holds.
                TO_MAIN.signal(());
                return Ok(n);
            }
        }
    }
}

impl Write for Link {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            if state() != State::Open {
                return Err(ErrorKind::ConnectionReset);
            }
            let was_empty = TO_BROKER.is_empty();
            if let Either::First(n) = select(TO_BROKER.write(buf), TO_SERVICE.wait()).await {
                // `carry` looks when the bytes begin to wait, and when they fill half the pipe.
                if was_empty || TO_BROKER.len() >= PIPE / 2 {
                    TO_MAIN.signal(());
                }
                return Ok(n);
            }
        }
    }

    /// What was written is on its way: `carry` gives it to the socket within [`GATHER`] (the
    /// pipe is the transport's buffer, as the socket's own is). Waiting here for the socket to
    /// take it would send every publication alone (minimq flushes after each).
    async fn flush(&mut self) -> Result<(), ErrorKind> {
        match state() {
            State::Open => Ok(()),
            _ => Err(ErrorKind::ConnectionReset),
        }
    }
}
