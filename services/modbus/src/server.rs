//! The Modbus/TCP connection server, generic over the transport (`embedded-io-async`), so the
//! same code serves embassy-net sockets on the target and std sockets on the host.
//!
//! Connection policy (spec §1.1): at most [`MAX_CONNECTIONS`] clients are served at once. A
//! board runs [`SOCKETS`] = `MAX_CONNECTIONS + 2` connection tasks, so a newcomer is always
//! accepted, even one right behind another; when that makes one too many, [`Slots`] closes the
//! connection idle the longest ([`Slots::admit_at`]). A connection in an exchange (not heard
//! from yet, or a request not answered yet) is not idle for [`GRACE_MS`]: a newcomer waits for
//! one to be idle, [`GRACE_MS`] at most, then the idlest goes anyway. Two rules stand against a
//! client that would starve the others
//! (IEC 62443-4-2 CR 7.1, docs/modbus.md):
//! - one source address holds at most [`PER_SOURCE`] connections: its own idlest one makes room
//!   for its next;
//! - while a write allow-list is set, a client it admits is never closed to make room for one it
//!   does not admit (such a newcomer is closed instead when only admitted clients are left).
//!
//! A connection idle for [`IDLE_TIMEOUT`] is closed.

use core::cell::RefCell;

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{with_timeout, Duration};
use embedded_io_async::{Read, Write};

use crate::frame::{classify, write_header, Frame, Header, MAX_ADU, MBAP_LEN};
use remodaq_shared::modbus::pdu::{handle_pdu, MAX_PDU};
use remodaq_shared::modbus::RegisterMap;

/// Clients served at once.
pub const MAX_CONNECTIONS: usize = remodaq_shared::sockets::MODBUS_CONNECTIONS;
/// Connections one source address may hold at once.
pub const PER_SOURCE: usize = remodaq_shared::sockets::MODBUS_PER_SOURCE;
/// A connection is in an exchange for at most this long (ms) without being idle: from its
/// opening until its client is heard from (a client sends its request right behind its
/// handshake; under QEMU's user network, in a flood, a few ms later), and from a request
/// received until it is answered. Also the longest a newcomer waits for room. Short, so that a
/// flood of silent connections makes room soon, and a newcomer holds a connection task (there
/// are two spare) briefly: a client stalling longer is idle.
pub const GRACE_MS: u64 = 50;
/// Connection tasks a board runs (`remodaq_shared::sockets::MODBUS_SOCKETS`: two more than
/// [`MAX_CONNECTIONS`]).
pub const SOCKETS: usize = remodaq_shared::sockets::MODBUS_SOCKETS;
/// A connection without a byte received for this long is closed.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(300);

/// Receive buffer: one full frame plus room for the start of a pipelined one.
const RX_BUF: usize = 2 * MAX_ADU;

/// Why a connection ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Ended {
    /// The peer closed its side.
    PeerClosed,
    /// Nothing received for [`IDLE_TIMEOUT`].
    Idle,
    /// Closed to make room for a new client.
    Evicted,
    /// A length field out of bounds: the stream is out of sync.
    Desync,
    /// The transport failed.
    Io,
}

/// Book-keeping of the connection tasks: which are serving a client, since when idle, and a
/// signal to close each one.
pub struct Slots<R: RawMutex, const N: usize> {
    /// For each slot serving a client, when it was last active, as a count of activity events
    /// (opens and received data) of all slots: the order of events is exact where a clock tick
    /// (1 ms on the QEMU board) would tie connections opened together in a flood, and a tie
    /// could close the newcomer instead of the one idle longest.
    last_activity: BlockingMutex<R, RefCell<Activity<N>>>,
    evict: [Signal<R, ()>; N],
    max_active: usize,
    per_source: usize,
}

/// Each slot's last activity, its client, and the count of activity events so far.
struct Activity<const N: usize> {
    last: [Option<u64>; N],
    client: [Client; N],
    /// Serving its client (a slot with `last` set and not admitted waits for room).
    admitted: [bool; N],
    /// The event of its connection (the order in which waiting newcomers are admitted).
    arrived: [u64; N],
    /// Where the client is in its exchange.
    phase: [Phase; N],
    /// When the exchange began: the connection, or the last data received (ms since start).
    since_ms: [u64; N],
    events: u64,
}

/// Where a connection is in its exchange with its client.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Connected, not heard from yet: its request may still be on the way.
    Fresh,
    /// A request received and not answered yet.
    Busy,
    /// Every request received is answered.
    Idle,
}

/// Who a slot serves: the source address, and whether the write allow-list (when set) admits it.
#[derive(Clone, Copy, Default)]
struct Client {
    ip: [u8; 4],
    protected: bool,
}

/// What [`Slots::open_at`] and [`Slots::admit_at`] decide for a new connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Admit {
    /// Serve it; the slot given, if any, was told to close to make room.
    Serve(Option<usize>),
    /// Close it: the write allow-list's clients hold every place.
    Refuse,
    /// Every connection that could make room is in an exchange: ask again a moment later.
    Wait,
}

impl<const N: usize> Activity<N> {
    /// One more event, on `slot`.
    fn event(&mut self, slot: usize) {
        self.events += 1;
        self.last[slot] = Some(self.events);
    }
}

/// How often a waiting newcomer asks again (ms).
const ADMIT_POLL_MS: u64 = 1;

impl<R: RawMutex, const N: usize> Slots<R, N> {
    /// `N` connection tasks of which at most `max_active` may serve a client at once, at most
    /// `per_source` of them the same source address.
    pub const fn new(max_active: usize, per_source: usize) -> Self {
        Self {
            last_activity: BlockingMutex::new(RefCell::new(Activity {
                last: [None; N],
                client: [Client { ip: [0; 4], protected: false }; N],
                admitted: [false; N],
                arrived: [0; N],
                phase: [Phase::Idle; N],
                since_ms: [0; N],
                events: 0,
            })),
            evict: [const { Signal::new() }; N],
            max_active,
            per_source,
        }
    }

    /// A new client at `ip` (`protected`: a write allow-list is set and admits it) on `slot`:
    /// waits until it is admitted ([`Self::open_at`], [`Self::admit_at`]); `Err` when it must
    /// be closed.
    pub async fn enter(&self, slot: usize, ip: [u8; 4], protected: bool) -> Result<Option<usize>, ()> {
        let mut admit = self.open_at(slot, ip, protected, embassy_time::Instant::now().as_millis());
        loop {
            match admit {
                Admit::Serve(victim) => return Ok(victim),
                Admit::Refuse => return Err(()),
                Admit::Wait => {
                    embassy_time::Timer::after_millis(ADMIT_POLL_MS).await;
                    admit = self.admit_at(slot, embassy_time::Instant::now().as_millis());
                }
            }
        }
    }

    /// Records a new client at `ip` on `slot` at `now_ms` (ms since start) and decides
    /// ([`Self::admit_at`]).
    pub fn open_at(&self, slot: usize, ip: [u8; 4], protected: bool, now_ms: u64) -> Admit {
        self.evict[slot].reset();
        self.last_activity.lock(|cell| {
            let mut activity = cell.borrow_mut();
            activity.event(slot);
            activity.arrived[slot] = activity.events;
            activity.client[slot] = Client { ip, protected };
            activity.admitted[slot] = false;
            activity.phase[slot] = Phase::Fresh;
            activity.since_ms[slot] = now_ms;
        });
        self.admit_at(slot, now_ms)
    }

    /// Decides at `now_ms` whether the newcomer on `slot` is served, and which connection closes
    /// to make room (spec §1.1: the one idle the longest; docs/modbus.md):
    /// - a connection in an exchange is not idle for [`GRACE_MS`] from its start: one not heard
    ///   from yet (its request is on the way) or one whose request is received and not answered
    ///   yet; among the others the one idle the longest goes;
    /// - when all are in an exchange, the newcomer waits (its request stays in its socket) until
    ///   one is idle, at most [`GRACE_MS`] from its connection, and then the idlest goes anyway;
    /// - waiting newcomers are admitted in the order they connected, except that an admitted
    ///   client of the write allow-list waits for nobody: it takes the place of the unadmitted
    ///   connection idle the longest at once, in an exchange or not.
    pub fn admit_at(&self, slot: usize, now_ms: u64) -> Admit {
        self.last_activity.lock(|cell| {
            let mut activity = cell.borrow_mut();
            let Activity { last, client, admitted, arrived, phase, since_ms, .. } = &mut *activity;
            let Client { ip, protected } = client[slot];
            let serving = |i: usize| i != slot && admitted[i] && last[i].is_some();
            let same_source = 1 + (0..N).filter(|&i| serving(i) && client[i].ip == ip).count();
            let active = 1 + (0..N).filter(|&i| serving(i)).count();
            // Waited its time: connections in an exchange may go too.
            let late = now_ms.saturating_sub(since_ms[slot]) >= GRACE_MS;
            let idle = |i: usize| phase[i] == Phase::Idle || now_ms.saturating_sub(since_ms[i]) >= GRACE_MS;
            // The idlest other connection among those `may_go` allows: idle ones first, and
            // those in an exchange only when `any`.
            let first = |may_go: &dyn Fn(usize) -> bool, any: bool| {
                (0..N).filter(|&i| serving(i) && may_go(i) && (any || idle(i))).min_by_key(|&i| (!idle(i), last[i]))
            };
            let unprotected = |i: usize| !client[i].protected;
            let victim = if same_source > self.per_source {
                first(&|i| client[i].ip == ip, late)
            } else if active > self.max_active {
                if protected {
                    // Unadmitted clients go first, at once; an admitted one only when no other
                    // is left.
                    first(&unprotected, true).or_else(|| first(&|_| true, late))
                } else if (0..N).any(|i| serving(i) && unprotected(i)) {
                    first(&unprotected, late)
                } else {
                    last[slot] = None;
                    return Admit::Refuse;
                }
            } else {
                None
            };
            let room_needed = same_source > self.per_source || active > self.max_active;
            // An earlier newcomer still waiting goes first (an admitted client does not queue
            // behind an unadmitted one).
            let earlier_waits = (0..N).any(|i| {
                i != slot
                    && !admitted[i]
                    && last[i].is_some()
                    && arrived[i] < arrived[slot]
                    && (client[i].protected || !protected)
            });
            if (room_needed && victim.is_none()) || (earlier_waits && !late && !protected) {
                return Admit::Wait;
            }
            admitted[slot] = true;
            if let Some(victim) = victim {
                last[victim] = None;
                admitted[victim] = false;
                self.evict[victim].signal(());
            }
            Admit::Serve(victim)
        })
    }

    /// Records data received on `slot` (a request, or part of one): it is in an exchange until
    /// [`Self::answered`]. False when the connection was closed to make room meanwhile: the data
    /// is then not to be handled (a write would be applied and never answered).
    pub fn touch(&self, slot: usize) -> bool {
        self.touch_at(slot, embassy_time::Instant::now().as_millis())
    }

    /// [`Self::touch`] at `now_ms` (ms since start).
    pub fn touch_at(&self, slot: usize, now_ms: u64) -> bool {
        self.last_activity.lock(|cell| {
            let mut activity = cell.borrow_mut();
            if activity.last[slot].is_none() {
                return false;
            }
            activity.event(slot);
            activity.phase[slot] = Phase::Busy;
            activity.since_ms[slot] = now_ms;
            true
        })
    }

    /// Records that every complete request received on `slot` is answered: it is idle.
    pub fn answered(&self, slot: usize) {
        self.last_activity.lock(|cell| cell.borrow_mut().phase[slot] = Phase::Idle);
    }

    /// Marks `slot` free.
    pub fn close(&self, slot: usize) {
        self.last_activity.lock(|cell| {
            let mut activity = cell.borrow_mut();
            activity.last[slot] = None;
            activity.admitted[slot] = false;
        });
    }

    /// Number of slots serving a client.
    pub fn active(&self) -> usize {
        self.last_activity.lock(|cell| {
            let activity = cell.borrow();
            (0..N).filter(|&i| activity.admitted[i] && activity.last[i].is_some()).count()
        })
    }
}

/// Serves one accepted connection from the client at `from` (IPv4; 0.0.0.0 when unknown) in
/// `slot` until it ends; the caller then closes the socket.
pub async fn serve<R: RawMutex, M: RegisterMap, T: Read + Write, const N: usize>(
    io: &mut T,
    from: [u8; 4],
    map: &Mutex<R, M>,
    slots: &Slots<R, N>,
    slot: usize,
) -> Ended {
    remodaq_shared::diagnostics::DIAGNOSTICS.connection(true);
    let protected = map.lock().await.protects(from);
    let ended = match slots.enter(slot, from, protected).await {
        Err(()) => {
            remodaq_shared::info!("modbus: connection limit reached, only admitted clients left: newcomer closed");
            Ended::Evicted
        }
        Ok(Some(victim)) => {
            remodaq_shared::info!("modbus: connection limit reached, closing idle connection {}", victim);
            serve_frames(io, from, map, slots, slot).await
        }
        Ok(None) => serve_frames(io, from, map, slots, slot).await,
    };
    slots.close(slot);
    remodaq_shared::diagnostics::DIAGNOSTICS.connection(false);
    ended
}

/// Transmit buffer: answers to every request already received are sent together, one flush
/// for all of them (pipelining); when the next answer might not fit, what is there goes first.
const TX_BUF: usize = 2 * MAX_ADU;

async fn serve_frames<R: RawMutex, M: RegisterMap, T: Read + Write, const N: usize>(
    io: &mut T,
    from: [u8; 4],
    map: &Mutex<R, M>,
    slots: &Slots<R, N>,
    slot: usize,
) -> Ended {
    let mut rx = [0u8; RX_BUF];
    let mut filled = 0usize;
    let mut tx = [0u8; TX_BUF];
    loop {
        // Answer every complete frame already buffered, in order, then send the answers with
        // one flush.
        let mut consumed = 0usize;
        let mut queued = 0usize;
        let mut desync = false;
        loop {
            match classify(&rx[consumed..filled]) {
                Frame::Incomplete => break,
                Frame::Desync => {
                    desync = true;
                    break;
                }
                Frame::Discard { len } => consumed += len,
                Frame::Request { header, len } => {
                    if queued + MAX_ADU > TX_BUF {
                        if let Err(ended) = send(io, &tx[..queued], false, slots, slot).await {
                            return ended;
                        }
                        queued = 0;
                    }
                    let pdu = &rx[consumed + MBAP_LEN..consumed + len];
                    let Some(out) = tx[queued..].first_chunk_mut::<MAX_ADU>() else { return Ended::Io };
                    queued += answer_request(map, from, header, pdu, out).await;
                    consumed += len;
                }
            }
        }
        if queued > 0 {
            if let Err(ended) = send(io, &tx[..queued], true, slots, slot).await {
                return ended;
            }
        }
        if desync {
            return Ended::Desync;
        }
        if filled > 0 {
            // Something was received (not at the start, when its client is not heard from
            // yet): every complete request in it is answered, and a partial one does not keep
            // the connection from being idle.
            slots.answered(slot);
        }
        rx.copy_within(consumed..filled, 0);
        filled -= consumed;

        // A partial frame never exceeds MAX_ADU (classify bounds the length), so there is room.
        let read = select(with_timeout(IDLE_TIMEOUT, io.read(&mut rx[filled..])), slots.evict[slot].wait()).await;
        match read {
            Either::First(Ok(Ok(0))) => return Ended::PeerClosed,
            Either::First(Ok(Ok(n))) => {
                filled += n;
                if !slots.touch(slot) {
                    return Ended::Evicted;
                }
            }
            Either::First(Ok(Err(_))) => return Ended::Io,
            Either::First(Err(_)) => return Ended::Idle,
            Either::Second(()) => return Ended::Evicted,
        }
    }
}

/// A peer that stops reading (a zero window) must not hold a connection task forever: sending
/// ends with the connection when it is evicted or has not progressed for this long.
const SEND_TIMEOUT: Duration = Duration::from_secs(10);

/// Sends `data` (and flushes when `flush`), unless the connection is evicted or stalls.
async fn send<R: RawMutex, T: Write, const N: usize>(
    io: &mut T,
    data: &[u8],
    flush: bool,
    slots: &Slots<R, N>,
    slot: usize,
) -> Result<(), Ended> {
    let sending = async {
        io.write_all(data).await?;
        if flush {
            io.flush().await?;
        }
        Ok::<(), T::Error>(())
    };
    match select(with_timeout(SEND_TIMEOUT, sending), slots.evict[slot].wait()).await {
        Either::First(Ok(Ok(()))) => Ok(()),
        Either::First(Ok(Err(_))) => Err(Ended::Io),
        Either::First(Err(_)) => Err(Ended::Idle),
        Either::Second(()) => Err(Ended::Evicted),
    }
}

/// Answers one request (its header and PDU) from the client at `from` into `out`: the
/// answer's header and PDU, and its length. Counted in the diagnostics.
pub async fn answer_request<R: RawMutex, M: RegisterMap>(
    map: &Mutex<R, M>,
    from: [u8; 4],
    header: Header,
    pdu: &[u8],
    out: &mut [u8; MAX_ADU],
) -> usize {
    let Some((head, body)) = split(out) else { return 0 };
    let n = handle_pdu(map, from, pdu, body).await;
    finish(head, header, body, n)
}

/// The header and PDU parts of a frame buffer (always `Some`: MAX_ADU is MBAP_LEN + MAX_PDU;
/// the compiler drops the check).
fn split(out: &mut [u8; MAX_ADU]) -> Option<(&mut [u8; MBAP_LEN], &mut [u8; MAX_PDU])> {
    let (head, body) = out.split_first_chunk_mut::<MBAP_LEN>()?;
    Some((head, body.first_chunk_mut::<MAX_PDU>()?))
}

#[inline]
fn finish(head: &mut [u8; MBAP_LEN], header: Header, body: &[u8; MAX_PDU], n: usize) -> usize {
    write_header(head, header, n);
    remodaq_shared::diagnostics::DIAGNOSTICS.answered(body[0] & 0x80 != 0);
    MBAP_LEN + n
}
