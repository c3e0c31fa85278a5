//! Modbus request latency measured inside the guest (issue #40's figure, docs/mqtt.md "Never in
//! the way"): from the LAN9118's interrupt that brought a request to the moment its answer is
//! written to the chip, on the guest's clock, for every request of one client connection; the
//! connection's median, 99th percentile and worst said in QEMU's log when it ends.
//!
//! Under QEMU's `-icount` (the `latency` run of `tools/qemu-e2e`) the guest's clock advances by
//! the instructions the guest runs while it runs: a thread of QEMU put aside by this PC stops the
//! clock with the guest, so the figure is the firmware's own (its executors, its interrupts, the
//! tasks a request waited behind) and not the PC's. Without `-icount` it is the wall clock's.
//!
//! The driver wrapper [`Probed`] sees every frame the stack takes and writes: a request is a
//! segment with data to the Modbus port, its answer the next segment with data back to the same
//! client port. One client is measured at a time: the last to send a request while no request
//! was pending (the requests of others meanwhile are not measured), until its connection ends. A request is taken as having arrived at the first interrupt since the chip's
//! receive FIFO was last found empty: frames before it in the FIFO (another connection's) count
//! as its wait, so the figure errs long, never short (but by the few µs a frame's interrupt waits
//! while the FIFO is looked at).

use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Context;

use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState, RxToken, TxToken};
use remodaq_net::backlog::tcp_segment;
use static_cell::ConstStaticCell;

use crate::time::counter_us;

/// No interrupt since the FIFO was found empty.
const NONE: u32 = u32::MAX;
/// The counter (µs) at the first LAN9118 interrupt since the receive FIFO was found empty.
static PENDING_SINCE: AtomicU32 = AtomicU32::new(NONE);

/// From the LAN9118's interrupt handler, before it wakes the stack.
pub(crate) fn interrupted() {
    let now = counter_us().min(NONE - 1);
    let _ = PENDING_SINCE.compare_exchange(NONE, now, Ordering::Relaxed, Ordering::Relaxed);
}

/// Requests a connection's summary holds: the e2e measure's 1000, and a margin.
const CAPACITY: usize = 1024;

/// One client connection's requests.
struct Measure {
    /// The Modbus port (the stored one).
    port: u16,
    /// The client's port: the first that sent a request since the last summary.
    client: Option<u16>,
    /// When the request not yet answered arrived (µs).
    arrived: Option<u32>,
    /// Each answered request's latency, µs, in order; `answered` may run past them.
    taken: [u32; CAPACITY],
    answered: usize,
}

impl Measure {
    /// A frame the stack took.
    fn received(&mut self, frame: &[u8]) {
        let Some(segment) = tcp_segment(frame).filter(|s| s.destination == self.port) else { return };
        // A request from another client while none is pending: that client is measured from
        // now on, so that a connection left open and idle does not keep the measure from the
        // next. The last one's figures are dropped, not said: the log's write would stop the
        // machine inside the new request's time.
        if segment.data > 0 && self.client != Some(segment.source) && self.arrived.is_none() {
            self.restart();
            self.client = Some(segment.source);
        }
        if self.client != Some(segment.source) {
            return;
        }
        if segment.data > 0 && self.arrived.is_none() {
            let pending = PENDING_SINCE.load(Ordering::Relaxed);
            self.arrived = Some(if pending == NONE { counter_us() } else { pending });
        }
        if segment.ends() {
            self.summary();
        }
    }

    /// A frame the stack wrote, as the chip will send it.
    fn sent(&mut self, frame: &[u8]) {
        let Some(segment) = tcp_segment(frame).filter(|s| s.source == self.port) else { return };
        if self.client != Some(segment.destination) {
            return;
        }
        if segment.data > 0 {
            if let Some(arrived) = self.arrived.take() {
                if let Some(slot) = self.taken.get_mut(self.answered) {
                    *slot = counter_us().wrapping_sub(arrived);
                }
                self.answered += 1;
            }
        }
        if segment.ends() {
            self.summary();
        }
    }

    /// The connection's figures in the log (a semihosting write: the machine stops for it, once
    /// a connection), and a fresh start.
    fn summary(&mut self) {
        let n = self.answered.min(CAPACITY);
        if let (Some(client), Some(taken)) = (self.client, self.taken.get_mut(..n)) {
            if let Some(&worst) = taken.iter().max() {
                taken.sort_unstable();
                let at = |q: usize| taken.get(n * q / 100).copied().unwrap_or(worst);
                cortex_m_semihosting::hprintln!(
                    "qemu board: Modbus answers to the client at port {}: {} requests, median {} us, 99 % {} us, worst {} us",
                    client,
                    self.answered,
                    at(50),
                    at(99),
                    worst
                );
            }
        }
        self.restart();
    }

    /// No client measured.
    fn restart(&mut self) {
        self.client = None;
        self.arrived = None;
        self.answered = 0;
    }
}

/// The board's Ethernet driver with the measure in its path (see the module's documentation).
pub struct Probed<D> {
    inner: D,
    measure: RefCell<Option<&'static mut Measure>>,
}

/// The measure, in a static of its own: inside the driver, its 4 KB were copied through the
/// start-up's stack with the network's runner (the main stack's mark rose by 11 KB).
static MEASURE: ConstStaticCell<Measure> =
    ConstStaticCell::new(Measure { port: 0, client: None, arrived: None, taken: [0; CAPACITY], answered: 0 });

impl<D: Driver> Probed<D> {
    /// `inner`, measuring requests to `port`; once (a second driver would measure nothing).
    pub fn new(inner: D, port: u16) -> Self {
        let mut measure = MEASURE.try_take();
        if let Some(measure) = measure.as_deref_mut() {
            measure.port = port;
        }
        Self { inner, measure: RefCell::new(measure) }
    }
}

/// A received frame, looked at before the stack takes it.
pub struct Rx<'a, T> {
    inner: T,
    measure: &'a RefCell<Option<&'static mut Measure>>,
}

impl<T: RxToken> RxToken for Rx<'_, T> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
        let Rx { inner, measure } = self;
        inner.consume(|frame| {
            // One token at a time is consumed: the borrow is always free.
            if let Some(measure) = measure.try_borrow_mut().ok().as_deref_mut().and_then(Option::as_deref_mut) {
                measure.received(frame);
            }
            f(frame)
        })
    }
}

/// A frame to send, looked at once the stack (and the backlog's wrapper) wrote it.
pub struct Tx<'a, T> {
    inner: T,
    measure: &'a RefCell<Option<&'static mut Measure>>,
}

impl<T: TxToken> TxToken for Tx<'_, T> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
        let Tx { inner, measure } = self;
        inner.consume(len, |frame| {
            let result = f(frame);
            if let Some(measure) = measure.try_borrow_mut().ok().as_deref_mut().and_then(Option::as_deref_mut) {
                measure.sent(frame);
            }
            result
        })
    }
}

impl<D: Driver> Driver for Probed<D> {
    type RxToken<'a>
        = Rx<'a, D::RxToken<'a>>
    where
        Self: 'a;
    type TxToken<'a>
        = Tx<'a, D::TxToken<'a>>
    where
        Self: 'a;

    fn receive(&mut self, cx: &mut Context) -> Option<(Self::RxToken<'_>, Self::TxToken<'_>)> {
        let Self { inner, measure } = self;
        // With interrupts masked: a frame that comes once the FIFO is found empty is marked by
        // its interrupt after the mark is cleared, never lost between the two.
        critical_section::with(|_| match inner.receive(cx) {
            Some((rx, tx)) => Some((Rx { inner: rx, measure: &*measure }, Tx { inner: tx, measure: &*measure })),
            None => {
                PENDING_SINCE.store(NONE, Ordering::Relaxed);
                None
            }
        })
    }

    fn transmit(&mut self, cx: &mut Context) -> Option<Self::TxToken<'_>> {
        let Self { inner, measure } = self;
        inner.transmit(cx).map(|tx| Tx { inner: tx, measure })
    }

    fn link_state(&mut self, cx: &mut Context) -> LinkState {
        self.inner.link_state(cx)
    }

    fn capabilities(&self) -> Capabilities {
        self.inner.capabilities()
    }

    fn hardware_address(&self) -> HardwareAddress {
        self.inner.hardware_address()
    }
}
