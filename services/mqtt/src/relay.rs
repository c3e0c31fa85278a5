//! TLS off the main executor (the STM32 and QEMU boards; docs/mqtt.md, "Never in the way"):
//! the handshake's arithmetic (P-256 key agreement and signature checks, tens of ms each on an
//! M4) runs in [`work`], a task of an executor that every other task preempts (the board's
//! background executor, in thread mode, below the main one), so that a Modbus request never
//! waits for it.
//!
//! The two sides share nothing but what is here, behind critical sections: four pipes (the
//! broker's bytes as they travel, encrypted, and the session's, in clear), the state of the link
//! and the request (the broker's name and the CA). The main executor keeps everything else: the
//! TCP socket (embassy-net's stack is not to be touched from two priorities), which [`Relay`]
//! pumps into the pipes while the session reads or writes, the session, the settings, the
//! counters. The worker holds the TLS connection and its record buffers.
//!
//! ```text
//!  main executor                              | background executor (thread mode)
//!  socket --pump--> FROM_BROKER --------------> TLS (work) --> RECEIVED --> session (Relay::read)
//!  socket <--pump-- TO_BROKER <--------------- TLS (work) <-- SENT <------ session (Relay::write)
//! ```

use core::cell::{Cell, RefCell};
use core::pin::pin;
use core::sync::atomic::{AtomicBool, Ordering};

use embassy_futures::select::{select, select3, Either, Either3};
use embassy_net::tcp::TcpSocket;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex as Cs;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::signal::Signal;
use embedded_io_async::{ErrorKind, ErrorType, Read, Write};
use remodaq_shared::mqtt::{MAX_CA, MAX_HOST};

use crate::tls::{BoardClock, ModuleRng, Refused, BUFFER, WRITE};

/// Encrypted bytes in each direction between the socket and the worker: at least a few records
/// of the module's (a publication is one) in flight.
const CIPHER: usize = 1024;
/// Clear bytes in each direction between the session and the worker.
const PLAIN: usize = 512;

/// The broker's bytes, encrypted, from the socket to the worker.
static FROM_BROKER: Pipe<Cs, CIPHER> = Pipe::new();
/// The module's bytes, encrypted, from the worker to the socket.
static TO_BROKER: Pipe<Cs, CIPHER> = Pipe::new();
/// The broker's bytes, in clear, from the worker to the session.
static RECEIVED: Pipe<Cs, PLAIN> = Pipe::new();
/// The session's bytes, in clear, from the session to the worker.
static SENT: Pipe<Cs, PLAIN> = Pipe::new();

/// Where the link is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// No link: the worker waits for a request.
    Idle,
    /// Requested: the worker does the handshake.
    Opening,
    /// The handshake passed: the worker carries the session's bytes.
    Open,
    /// The handshake failed, for this reason.
    Refused(Refused),
    /// The link ended (the broker's alert or close, a record that did not decrypt).
    Ended,
}

static STATE: Mutex<Cs, Cell<State>> = Mutex::new(Cell::new(State::Idle));
/// The main side asks the worker to drop the link (answered by [`State::Idle`]).
static STOP: AtomicBool = AtomicBool::new(false);
/// Wakes the worker: a request, or [`STOP`].
static TO_WORKER: Signal<Cs, ()> = Signal::new();
/// Wakes the main side: the state changed, or the worker took from or put into the encrypted
/// pipes.
static TO_MAIN: Signal<Cs, ()> = Signal::new();

/// What the worker connects to.
struct Request {
    host: heapless::String<MAX_HOST>,
    ca: heapless::Vec<u8, MAX_CA>,
}

static REQUEST: Mutex<Cs, RefCell<Request>> =
    Mutex::new(RefCell::new(Request { host: heapless::String::new(), ca: heapless::Vec::new() }));

fn state() -> State {
    STATE.lock(Cell::get)
}

fn set_state(s: State) {
    STATE.lock(|c| c.set(s));
}

/// The worker's side of the encrypted pipes: the TLS connection's transport.
#[derive(Clone, Copy)]
struct Encrypted;

impl ErrorType for Encrypted {
    type Error = ErrorKind;
}

impl Read for Encrypted {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        let n = FROM_BROKER.read(buf).await;
        // Room again for what the socket holds.
        TO_MAIN.signal(());
        Ok(n)
    }
}

impl Write for Encrypted {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        let n = TO_BROKER.write(buf).await;
        TO_MAIN.signal(());
        Ok(n)
    }

    /// What is written is in the pipe, which the main side empties into the socket.
    async fn flush(&mut self) -> Result<(), ErrorKind> {
        Ok(())
    }
}

/// Until the main side asks the worker to drop the link.
async fn stopped() {
    while !STOP.load(Ordering::Acquire) {
        TO_WORKER.wait().await;
    }
}

/// The worker: opens each requested link and carries its bytes, until asked to stop, for
/// ever. Run it in a task of the board's background executor (preempted by the main one); its
/// future holds TLS's record buffers ([`BUFFER`]): pin it where it is made.
pub async fn work() -> ! {
    let mut buffer = [0u8; BUFFER];
    let mut host = heapless::String::<MAX_HOST>::new();
    let mut ca = heapless::Vec::<u8, MAX_CA>::new();
    loop {
        while state() != State::Opening {
            TO_WORKER.wait().await;
        }
        REQUEST.lock(|r| {
            let r = r.borrow();
            host.clone_from(&r.host);
            ca.clone_from(&r.ca);
        });
        let (read, write) = buffer.split_at_mut(BUFFER - WRITE);
        // The connection stays here; the futures handle it by reference. Made in place, as
        // every large future here (either would be copied through the stack).
        let mut tls = crate::tls::connection(Encrypted, read, write);
        let opened = {
            let opening = pin!(crate::tls::handshake::<_, _, BoardClock>(&mut tls, &ca, &host, ModuleRng));
            select(opening, stopped()).await
        };
        if let Either::First(opened) = opened {
            match opened {
                Ok(()) => {
                    set_state(State::Open);
                    TO_MAIN.signal(());
                    let (reader, writer) = tls.split();
                    if let Either::First(()) = select(pin!(carry(reader, writer)), stopped()).await {
                        set_state(State::Ended);
                        TO_MAIN.signal(());
                        stopped().await;
                    }
                }
                Err(why) => {
                    set_state(State::Refused(why));
                    TO_MAIN.signal(());
                    stopped().await;
                }
            }
        }
        set_state(State::Idle);
        TO_MAIN.signal(());
    }
}

/// Carries the session's bytes through the open link, until it ends.
async fn carry<R: Read, W: Write>(mut reader: R, mut writer: W) {
    let down = async {
        let mut b = [0u8; 256];
        loop {
            match reader.read(&mut b).await {
                Ok(n) if n > 0 => RECEIVED.write_all(&b[..n]).await,
                _ => return,
            }
        }
    };
    let up = async {
        let mut b = [0u8; 256];
        loop {
            let n = SENT.read(&mut b).await;
            if writer.write_all(&b[..n]).await.is_err() || writer.flush().await.is_err() {
                return;
            }
        }
    };
    select(down, up).await;
}

/// Drops the link the worker holds, if any (waits until it did).
pub async fn stop() {
    while state() != State::Idle {
        STOP.store(true, Ordering::Release);
        TO_WORKER.signal(());
        TO_MAIN.wait().await;
    }
}

/// TLS to the broker named `host` (its chain checked against `ca`, DER) over `socket`, already
/// connected to it: the handshake by the worker, while this pumps the socket.
pub async fn open<'s, 'b>(socket: &'s mut TcpSocket<'b>, ca: &[u8], host: &str) -> Result<Relay<'s, 'b>, Refused> {
    stop().await;
    for pipe in [&FROM_BROKER, &TO_BROKER] {
        pipe.clear();
    }
    RECEIVED.clear();
    SENT.clear();
    let fits = REQUEST.lock(|r| {
        let mut r = r.borrow_mut();
        r.host.clear();
        r.ca.clear();
        r.host.push_str(host).is_ok() && r.ca.extend_from_slice(ca).is_ok()
    });
    if !fits {
        return Err(Refused::Certificate);
    }
    STOP.store(false, Ordering::Release);
    set_state(State::Opening);
    TO_WORKER.signal(());
    let mut relay = Relay { socket };
    match relay.pump(State::Opening, || false).await {
        Some(State::Open) => Ok(relay),
        Some(State::Refused(why)) => Err(why),
        _ => Err(Refused::Handshake),
    }
}

/// The session's end of an open link ([`open`]): its bytes in clear, the socket pumped while
/// it reads or writes.
pub struct Relay<'s, 'b> {
    socket: &'s mut TcpSocket<'b>,
}

impl Relay<'_, '_> {
    /// Moves the encrypted bytes between the socket and the worker while the link is in
    /// `while_in` and `done` is false: `Some(state)` when the link left it (or `done` held:
    /// the same state), `None` when the socket closed or failed.
    async fn pump(&mut self, while_in: State, done: impl Fn() -> bool) -> Option<State> {
        let socket = &mut *self.socket;
        loop {
            let now = state();
            if now != while_in || done() {
                return Some(now);
            }
            // What can move now moves: the closures run at once (the socket can take or give),
            // so nothing is held between the pipe and the socket when this is dropped.
            if !TO_BROKER.is_empty() && socket.can_send() {
                let sent = socket.write_with(|b| {
                    let n = TO_BROKER.try_read(b).unwrap_or(0);
                    (n, n)
                });
                if sent.await.is_err() {
                    return None;
                }
                continue;
            }
            if socket.can_recv() && !FROM_BROKER.is_full() {
                let received = socket.read_with(|b| {
                    let n = FROM_BROKER.try_write(b).unwrap_or(0);
                    (n, n)
                });
                if received.await.is_err() {
                    return None;
                }
                continue;
            }
            if !socket.may_recv() {
                return None;
            }
            // Then wait for the socket or the worker.
            let readable = async {
                if FROM_BROKER.is_full() {
                    core::future::pending::<()>().await;
                }
                socket.wait_read_ready().await;
            };
            let writable = async {
                if TO_BROKER.is_empty() {
                    core::future::pending::<()>().await;
                }
                socket.wait_write_ready().await;
            };
            match select3(readable, writable, TO_MAIN.wait()).await {
                Either3::First(()) | Either3::Second(()) | Either3::Third(()) => {}
            }
        }
    }
}

impl ErrorType for Relay<'_, '_> {
    type Error = ErrorKind;
}

impl Read for Relay<'_, '_> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        if buf.is_empty() {
            return Ok(0);
        }
        if let Ok(n) = RECEIVED.try_read(buf) {
            return Ok(n);
        }
        match select(RECEIVED.read(buf), self.pump(State::Open, || false)).await {
            Either::First(n) => Ok(n),
            Either::Second(_) => Err(ErrorKind::ConnectionReset),
        }
    }
}

impl Write for Relay<'_, '_> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        if buf.is_empty() {
            return Ok(0);
        }
        match select(SENT.write(buf), self.pump(State::Open, || false)).await {
            Either::First(n) => Ok(n),
            Either::Second(_) => Err(ErrorKind::ConnectionReset),
        }
    }

    async fn flush(&mut self) -> Result<(), ErrorKind> {
        // Until the worker took all of it and the socket the records it made (or the moment
        // between the two: what the worker holds goes at the next pump, as all the rest).
        match self.pump(State::Open, || SENT.is_empty() && TO_BROKER.is_empty()).await {
            Some(State::Open) => Ok(()),
            _ => Err(ErrorKind::ConnectionReset),
        }
    }
}
