//! The gate: a port's backlog shared by the network runner and the connection tasks
//! ([`SynGate`], seen through the [`Gate`] trait), and the ports' gates on the boards.

use core::cell::RefCell;
use core::task::{Context, Waker};

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;

use remodaq_shared::sockets::MODBUS_SOCKETS as SOCKETS;

use super::frame::Peer;
use super::queue::{Backlog, Verdict, HELD, MAX_SYN_FRAME};

/// The backlog shared by the network runner (through [`Backlogged`](super::Backlogged)) and the
/// connection tasks.
pub struct SynGate<const H: usize, const S: usize> {
    state: Mutex<CriticalSectionRawMutex, RefCell<(Backlog<H, S>, Option<Waker>)>>,
}

impl<const H: usize, const S: usize> Default for SynGate<H, S> {
    fn default() -> Self {
        Self::new()
    }
}

/// The Modbus port's gate.
pub type ModbusGate = SynGate<HELD, SOCKETS>;

/// The Modbus port's backlog on the boards that run embassy-net (the CPU's alone: in the CCM
/// where the board has one, feature `ccm`).
#[cfg_attr(feature = "ccm", unsafe(link_section = ".bss.ccm.MODBUS_BACKLOG"))]
pub static MODBUS_BACKLOG: ModbusGate = SynGate::new();

/// SYNs for the web console's port held at most: a browser opens up to 6 connections to a
/// host at once (a page's files), and the console serves
/// [`WEB_CONNECTIONS`](remodaq_shared::sockets::WEB_CONNECTIONS) at a time; the rest wait here instead of
/// being reset.
#[cfg(feature = "web")]
pub const WEB_HELD: usize = 8;

/// The web console port's gate.
#[cfg(feature = "web")]
pub type WebGate = SynGate<WEB_HELD, { remodaq_shared::sockets::WEB_CONNECTIONS }>;

/// The web console port's backlog on the boards that run embassy-net (in SRAM: the STM32 8350's
/// CCM is full with MQTT's task, docs/mqtt.md "Sizes").
#[cfg(feature = "web")]
pub static WEB_BACKLOG: WebGate = SynGate::new();

/// Every port's gate, in the order they see a frame.
pub static GATES: &[&dyn Gate] = &[
    &MODBUS_BACKLOG,
    #[cfg(feature = "web")]
    &WEB_BACKLOG,
];

/// The module's MAC and IPv4 address to every gate (the board, when its network starts; see
/// [`Backlog::identify`]): `per_source` for the Modbus port; the web port's SYNs come from
/// browsers, which open several connections at once, so one source may fill its backlog.
pub fn identify(mac: [u8; 6], ip: [u8; 4], per_source: usize) {
    MODBUS_BACKLOG.identify(mac, ip, per_source);
    #[cfg(feature = "web")]
    WEB_BACKLOG.identify(mac, ip, WEB_HELD);
}

/// A port's gate as the connection tasks and the driver wrapper see it.
pub trait Gate: Sync {
    /// The port its tasks listen on (0 before the first listens).
    fn port(&self) -> u16;
    /// A connection task listens on `port` (its socket already in LISTEN): a held SYN may go
    /// to the stack now, so the network runner is woken.
    fn listening(&self, port: u16);
    /// A connection task's accept ended, with a connection from `peer` or without.
    fn accepted(&self, peer: Option<Peer>);
    /// A frame from the wire at `now_ms`: to the stack, or held.
    fn arrive(&self, frame: &[u8], now_ms: u64) -> Verdict;
    /// Whether a held SYN can go to the stack now: `Ok`, or when to look again if one waits
    /// (the runner's waker is kept for when a task listens).
    fn ready(&self, now_ms: u64, cx: &Context<'_>) -> Result<(), Option<u64>>;
    /// The oldest held SYN, copied into `out`, if a task listens for it now: its length.
    fn release(&self, now_ms: u64, out: &mut [u8; MAX_SYN_FRAME]) -> Option<usize>;
}

impl<const H: usize, const S: usize> SynGate<H, S> {
    /// Empty.
    pub const fn new() -> Self {
        Self { state: Mutex::new(RefCell::new((Backlog::new(), None))) }
    }

    pub(super) fn with<T>(&self, f: impl FnOnce(&mut Backlog<H, S>, &mut Option<Waker>) -> T) -> T {
        self.state.lock(|cell| {
            let mut state = cell.borrow_mut();
            let (backlog, waker) = &mut *state;
            f(backlog, waker)
        })
    }

    /// The module's MAC and IPv4 address, and the SYNs one source may have held
    /// ([`Backlog::identify`]).
    pub fn identify(&self, mac: [u8; 6], ip: [u8; 4], per_source: usize) {
        self.with(|backlog, _| backlog.identify(mac, ip, per_source));
    }
}

impl<const H: usize, const S: usize> Gate for SynGate<H, S> {
    fn port(&self) -> u16 {
        self.with(|backlog, _| backlog.port)
    }

    fn listening(&self, port: u16) {
        let waker = self.with(|backlog, waker| {
            backlog.listening(port);
            if backlog.held() > 0 {
                waker.take()
            } else {
                None
            }
        });
        if let Some(waker) = waker {
            waker.wake();
        }
    }

    fn accepted(&self, peer: Option<Peer>) {
        self.with(|backlog, _| backlog.accepted(peer));
    }

    fn arrive(&self, frame: &[u8], now_ms: u64) -> Verdict {
        self.with(|backlog, _| backlog.arrive(frame, now_ms))
    }

    fn ready(&self, now_ms: u64, cx: &Context<'_>) -> Result<(), Option<u64>> {
        self.with(|backlog, waker| {
            if backlog.ready(now_ms) {
                return Ok(());
            }
            if backlog.held() > 0 {
                *waker = Some(cx.waker().clone());
            }
            Err(backlog.next_change())
        })
    }

    fn release(&self, now_ms: u64, out: &mut [u8; MAX_SYN_FRAME]) -> Option<usize> {
        self.with(|backlog, _| backlog.release(now_ms, out))
    }
}
