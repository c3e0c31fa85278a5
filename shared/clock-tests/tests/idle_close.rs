//! The connection server closes a connection idle for 5 minutes (spec §1.1, `IDLE_TIMEOUT`),
//! on a clock this test advances by hand: a request answered, then silence. At 299.999 s
//! since the last request the connection is still open; at 300 s it ends as idle. A request
//! in between restarts the count.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::Future;
use std::pin::pin;
use std::rc::Rc;
use std::task::{Context, Poll, Waker};

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, MockDriver};
use remodaq_modbus::server::{serve, Ended, Slots, IDLE_TIMEOUT};
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};

/// One register, 40001, reading 1234h.
struct OneRegister;

impl RegisterMap for OneRegister {
    fn access(&self, table: Table, addr: u16) -> Access {
        if (table, addr) == (Table::Registers, 0) {
            Access::Read
        } else {
            Access::None
        }
    }
    fn read(&mut self, _: Table, _: u16) -> u16 {
        0x1234
    }
    fn validate(&self, _: u16, _: &WriteValues<'_>) -> Result<(), Exception> {
        Ok(())
    }
    async fn apply(&mut self, _: u16, _: &WriteValues<'_>) -> Result<(), Exception> {
        Ok(())
    }
}

/// The mock clock is one static: the tests take turns.
fn clock() -> (std::sync::MutexGuard<'static, ()>, &'static MockDriver) {
    static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let clock = MockDriver::get();
    clock.reset();
    (turn, clock)
}

const REQUEST: [u8; 12] = [0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 1];

/// The map, one connection slot, and a peer that has sent one request.
fn connection() -> (Mutex<NoopRawMutex, OneRegister>, Slots<NoopRawMutex, 1>, Rc<RefCell<VecDeque<Vec<u8>>>>) {
    let peer = Rc::new(RefCell::new(VecDeque::from([REQUEST.to_vec()])));
    (Mutex::new(OneRegister), Slots::new(1, 1), peer)
}

#[test]
fn a_connection_idle_for_five_minutes_is_closed() {
    assert_eq!(IDLE_TIMEOUT, Duration::from_secs(300), "spec §1.1: 5 minutes");
    let (_turn, clock) = clock();
    let (map, slots, peer) = connection();
    let mut io = Shared(peer, 0);
    {
        let mut server = pin!(serve(&mut io, [127, 0, 0, 1], &map, &slots, 0));
        let mut cx = Context::from_waker(Waker::noop());
        assert!(server.as_mut().poll(&mut cx).is_pending(), "answered, then waiting");
        clock.advance(Duration::from_millis(299_999));
        assert!(server.as_mut().poll(&mut cx).is_pending(), "open at 299.999 s");
        clock.advance(Duration::from_millis(1));
        assert_eq!(server.as_mut().poll(&mut cx), Poll::Ready(Ended::Idle), "closed at 300 s");
    }
    assert_eq!(io.1, 1, "one answer");
    assert_eq!(slots.active(), 0, "slot released");
}

#[test]
fn a_request_restarts_the_idle_count() {
    let (_turn, clock) = clock();
    let (map, slots, peer) = connection();
    let mut io = Shared(peer.clone(), 0);
    let mut server = pin!(serve(&mut io, [127, 0, 0, 1], &map, &slots, 0));
    let mut cx = Context::from_waker(Waker::noop());
    assert!(server.as_mut().poll(&mut cx).is_pending());
    clock.advance(Duration::from_secs(200));
    assert!(server.as_mut().poll(&mut cx).is_pending());
    peer.borrow_mut().push_back(REQUEST.to_vec());
    assert!(server.as_mut().poll(&mut cx).is_pending(), "second request answered");
    clock.advance(Duration::from_millis(299_999));
    assert!(server.as_mut().poll(&mut cx).is_pending(), "499.999 s since the first, 299.999 s since the last");
    clock.advance(Duration::from_millis(1));
    assert_eq!(server.as_mut().poll(&mut cx), Poll::Ready(Ended::Idle), "300 s since the last request");
}

/// A peer whose incoming frames the test can add while the server runs.
struct Shared(Rc<RefCell<VecDeque<Vec<u8>>>>, usize);

impl embedded_io_async::ErrorType for Shared {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Read for Shared {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        std::future::poll_fn(|_| match self.0.borrow_mut().pop_front() {
            Some(frame) => {
                buf[..frame.len()].copy_from_slice(&frame);
                Poll::Ready(Ok(frame.len()))
            }
            None => Poll::Pending,
        })
        .await
    }
}

impl embedded_io_async::Write for Shared {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.1 += 1;
        Ok(buf.len())
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
