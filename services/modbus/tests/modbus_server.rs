//! Framing tests through the connection server (spec §1.1): MBAP rules, pipelining, segments.
#[path = "../../../shared/tests/common/mod.rs"]
mod common;

use common::{hex, Script, TestMap};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::mutex::Mutex;
use futures_executor::block_on;
use remodaq_modbus::server::{serve, Admit, Ended, Slots, GRACE_MS, PER_SOURCE};

fn run(segments: &[&[u8]]) -> (Vec<u8>, Ended) {
    let map = Mutex::<NoopRawMutex, _>::new(TestMap::default());
    let slots = Slots::<NoopRawMutex, 2>::new(1, PER_SOURCE);
    let mut io = Script::new(segments);
    let ended = block_on(serve(&mut io, [127, 0, 0, 1], &map, &slots, 0));
    assert_eq!(slots.active(), 0, "slot released");
    (io.outgoing, ended)
}

fn one(frame: &str) -> (Vec<u8>, Ended) {
    run(&[&hex(frame)])
}

#[test]
fn manual_framing_example() {
    // 8318 manual Figure 2.1/2.2: read two registers; the manual prints the response's length
    // field as 06, the correct value for 1 + 1 + 1 + 4 bytes is 07 (erratum).
    let map = Mutex::<NoopRawMutex, _>::new(TestMap::default());
    block_on(async { map.lock().await.regs[6..8].copy_from_slice(&[0x7FFF, 0x7FFF]) });
    let slots = Slots::<NoopRawMutex, 1>::new(1, PER_SOURCE);
    let mut io = Script::new(&[&hex("00 00 00 00 00 06 01 04 00 06 00 02")]);
    assert_eq!(block_on(serve(&mut io, [127, 0, 0, 1], &map, &slots, 0)), Ended::PeerClosed);
    assert_eq!(io.outgoing, hex("00 00 00 00 00 07 01 04 04 7F FF 7F FF"));
}

#[test]
fn transaction_and_unit_ids_are_echoed() {
    for unit in ["00", "01", "FF"] {
        let (out, ended) = one(&format!("12 34 00 00 00 06 {unit} 03 01 00 00 01"));
        assert_eq!(out, hex(&format!("12 34 00 00 00 05 {unit} 03 02 83 18")));
        assert_eq!(ended, Ended::PeerClosed);
    }
}

#[test]
fn exception_response_is_framed() {
    let (out, _) = one("00 07 00 00 00 06 01 03 02 00 00 01");
    assert_eq!(out, hex("00 07 00 00 00 03 01 83 02"));
}

#[test]
fn protocol_id_not_zero_is_discarded_and_connection_kept() {
    let (out, ended) = one("00 01 00 01 00 06 01 03 01 00 00 01 00 02 00 00 00 06 01 03 01 00 00 01");
    assert_eq!(out, hex("00 02 00 00 00 05 01 03 02 83 18"));
    assert_eq!(ended, Ended::PeerClosed);
}

#[test]
fn length_1_and_255_close_the_connection() {
    for len in ["00 01", "00 FF", "00 00", "01 00"] {
        let (out, ended) = one(&format!("00 01 00 00 {len} 01 03 01 00 00 01"));
        assert!(out.is_empty());
        assert_eq!(ended, Ended::Desync, "length {len}");
    }
    // A good request before the bad header is still answered.
    let (out, ended) = one("00 01 00 00 00 06 01 03 01 00 00 01 00 02 00 00 00 01 01");
    assert_eq!(out, hex("00 01 00 00 00 05 01 03 02 83 18"));
    assert_eq!(ended, Ended::Desync);
}

#[test]
fn length_2_is_a_bare_function_code() {
    let (out, _) = one("00 01 00 00 00 02 01 03");
    assert_eq!(out, hex("00 01 00 00 00 03 01 83 03"));
}

#[test]
fn write_of_123_registers_in_one_frame() {
    // 16 with 123 registers: 1 + 2 + 2 + 1 + 246 = 252 PDU bytes + unit = length 253.
    let values = "00 01 ".repeat(123);
    let (out, ended) = one(&format!("00 09 00 00 00 FD 01 10 00 00 00 7B F6 {values}"));
    assert_eq!(out, hex("00 09 00 00 00 06 01 10 00 00 00 7B"));
    assert_eq!(ended, Ended::PeerClosed);
}

#[test]
fn length_254_is_in_bounds() {
    // The largest legal frame (253-byte PDU) is read whole and answered: here a 123-register
    // write with one byte too many, so exception 03, and the connection stays in sync.
    let values = "00 01 ".repeat(123);
    let (out, ended) =
        one(&format!("00 09 00 00 00 FE 01 10 00 00 00 7B F6 {values} 00 00 0A 00 00 00 06 01 03 01 00 00 01"));
    assert_eq!(out, hex("00 09 00 00 00 03 01 90 03 00 0A 00 00 00 05 01 03 02 83 18"));
    assert_eq!(ended, Ended::PeerClosed);
}

#[test]
fn two_requests_in_one_segment_are_answered_in_order() {
    let (out, _) = one("00 01 00 00 00 06 01 06 00 05 00 2A 00 02 00 00 00 06 01 03 00 05 00 01");
    assert_eq!(out, hex("00 01 00 00 00 06 01 06 00 05 00 2A 00 02 00 00 00 05 01 03 02 00 2A"));
}

#[test]
fn one_request_in_three_segments_is_reassembled() {
    let frame = hex("00 03 00 00 00 06 01 03 01 00 00 01");
    let (out, ended) = run(&[&frame[..2], &frame[2..9], &frame[9..]]);
    assert_eq!(out, hex("00 03 00 00 00 05 01 03 02 83 18"));
    assert_eq!(ended, Ended::PeerClosed);
}

#[test]
fn byte_at_a_time_pipelined_stream() {
    let stream = hex("00 01 00 00 00 06 01 03 01 00 00 01 00 02 00 00 00 06 01 03 01 00 00 01");
    let segments: Vec<&[u8]> = stream.chunks(1).collect();
    let (out, _) = run(&segments);
    assert_eq!(out, hex("00 01 00 00 00 05 01 03 02 83 18 00 02 00 00 00 05 01 03 02 83 18"));
}

/// A distinct source address per slot.
fn ip(slot: usize) -> [u8; 4] {
    [10, 0, 0, slot as u8]
}

#[test]
fn one_source_holds_at_most_four_connections() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    let hog = [10, 9, 9, 9];
    assert_eq!(slots.open_at(0, ip(0), false, 0), Admit::Serve(None), "another client, idle the longest");
    for slot in 1..=4 {
        assert_eq!(slots.open_at(slot, hog, false, 0), Admit::Serve(None));
    }
    // The fifth from the same address closes that address's own idlest, not the other client.
    assert_eq!(slots.open_at(5, hog, false, 1000), Admit::Serve(Some(1)));
    assert_eq!(slots.open_at(6, hog, false, 1000), Admit::Serve(Some(2)));
    assert_eq!(slots.active(), 5);
}

#[test]
fn an_admitted_client_is_never_closed_for_one_the_allow_list_does_not_admit() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    let master = [192, 168, 0, 10];
    assert_eq!(
        slots.open_at(0, master, true, 0),
        Admit::Serve(None),
        "the SCADA master, on the allow-list, idle the longest"
    );
    for slot in 1..8 {
        assert_eq!(slots.open_at(slot, ip(slot), false, 0), Admit::Serve(None));
    }
    // 64 other clients, one after another: each closes the idlest unadmitted one, never the master.
    let mut slot = 8;
    for n in 0..64 {
        let Admit::Serve(Some(victim)) = slots.open_at(slot, [10, 1, 0, n], false, 1000 * (u64::from(n) + 1)) else {
            panic!("a connection closes")
        };
        assert_ne!(victim, 0, "the master stays");
        slot = victim;
    }
    // When only admitted clients are left, an unadmitted newcomer is the one closed.
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    for slot in 0..8 {
        assert_eq!(slots.open_at(slot, [192, 168, 0, slot as u8], true, 0), Admit::Serve(None));
    }
    assert_eq!(slots.open_at(8, [10, 2, 0, 1], false, 1000), Admit::Refuse, "the newcomer goes");
    assert_eq!(
        slots.open_at(9, [192, 168, 0, 99], true, 1000),
        Admit::Serve(Some(0)),
        "an admitted newcomer takes the idlest"
    );
}

/// Spec §1.1 closes the connection idle the longest to make room (docs/modbus.md). A
/// connection in an exchange is not idle for its first 50 ms: one whose request is still on
/// the way (under QEMU a flood's connections finish their handshakes after a newcomer's), and
/// one whose request is received and not answered yet. When only those are left, the newcomer
/// waits until one is idle (newcomers in the order they came), 50 ms at most.
#[test]
fn a_connection_in_an_exchange_is_not_closed_in_its_first_50_ms() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    for slot in 0..7 {
        assert_eq!(slots.open_at(slot, ip(slot), false, 0), Admit::Serve(None), "the flood");
        slots.touch_at(slot, 1); // each sends its request at once, answered at once
        slots.answered(slot);
    }
    assert_eq!(slots.open_at(7, ip(7), false, 10), Admit::Serve(None), "a newcomer, its request not in yet");
    assert_eq!(slots.open_at(8, ip(8), false, 12), Admit::Serve(Some(0)), "the idlest answered one");
    slots.touch_at(8, 12); // a request in, not answered yet
    assert_eq!(slots.open_at(9, ip(9), false, 13), Admit::Serve(Some(1)));
    slots.touch_at(9, 13);
    for (slot, at, victim) in [(0, 20, 2), (1, 21, 3), (2, 22, 4), (3, 23, 5), (4, 24, 6)] {
        assert_eq!(slots.open_at(slot, ip(slot), false, at), Admit::Serve(Some(victim)), "idle ones, never 7");
        slots.touch_at(slot, at);
    }
    // Every other connection is in an exchange: the next ones wait, in order.
    assert_eq!(slots.open_at(5, ip(5), false, 30), Admit::Wait, "nothing in progress is cut");
    assert_eq!(slots.open_at(6, ip(6), false, 31), Admit::Wait);
    assert_eq!(slots.active(), 8);
    slots.answered(9);
    slots.answered(8);
    assert_eq!(slots.admit_at(6, 35), Admit::Wait, "5 came first");
    assert_eq!(slots.admit_at(5, 35), Admit::Serve(Some(8)), "answered: 8 is idle, the longest");
    assert_eq!(slots.admit_at(6, 36), Admit::Serve(Some(9)));
    // Past its 50 ms a connection never heard from (7) is idle: it goes next.
    assert_eq!(slots.open_at(8, ip(8), false, 61), Admit::Serve(Some(7)));
    // A newcomer waits 50 ms at most: then the idlest goes, in an exchange or not.
    for slot in [0, 1, 2, 3, 4, 5, 6, 8] {
        slots.touch_at(slot, 100);
    }
    assert_eq!(slots.open_at(7, ip(7), false, 90), Admit::Wait);
    assert_eq!(slots.admit_at(7, 139), Admit::Wait);
    assert_eq!(slots.admit_at(7, 140), Admit::Serve(Some(0)));
    // Data arriving on a connection already closed to make room is not handled.
    assert!(!slots.touch_at(0, 141), "0 was closed");
    assert!(slots.touch_at(7, 141));
}

/// A connection not heard from yet is not closed in its first 50 ms (its request is on the
/// way); a newcomer waits for that, then the one connected first goes.
#[test]
fn a_connection_not_heard_from_is_kept_for_its_first_50_ms() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    for slot in 0..8 {
        assert_eq!(slots.open_at(slot, ip(slot), false, slot as u64), Admit::Serve(None));
    }
    assert_eq!(slots.open_at(8, ip(8), false, 20), Admit::Wait);
    assert_eq!(slots.admit_at(8, 49), Admit::Wait, "slot 0 connected 49 ms ago");
    assert_eq!(slots.admit_at(8, 50), Admit::Serve(Some(0)));
    slots.touch_at(1, 50); // slot 1's request arrives: it is kept, slot 2 goes next
    assert_eq!(slots.open_at(0, ip(0), false, 52), Admit::Serve(Some(2)));
}

/// An admitted client (write allow-list) waits for nobody: while every unadmitted connection is
/// in an exchange, it takes the place of the unadmitted one idle the longest at once.
#[test]
fn an_admitted_newcomer_takes_the_place_of_a_busy_unadmitted_one() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    for slot in 0..8 {
        assert_eq!(slots.open_at(slot, ip(slot), false, 0), Admit::Serve(None));
        slots.touch_at(slot, 0);
    }
    assert_eq!(slots.open_at(8, ip(8), false, 1), Admit::Wait, "an unadmitted newcomer waits its turn");
    assert_eq!(slots.open_at(9, [192, 168, 0, 10], true, 2), Admit::Serve(Some(0)), "the master at once");
    assert_eq!(slots.admit_at(8, 40), Admit::Wait);
    assert_eq!(slots.admit_at(8, 51), Admit::Serve(Some(1)), "the other, after its 50 ms");
}

/// An admitted newcomer never closes another admitted client while an unadmitted one is
/// connected, even one in an exchange.
#[test]
fn an_admitted_newcomer_closes_an_unadmitted_one_before_an_admitted_one() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    let master = [192, 168, 0, 10];
    assert_eq!(slots.open_at(0, master, true, 0), Admit::Serve(None), "a master, idle");
    slots.touch_at(0, 0);
    slots.answered(0);
    for slot in 1..8 {
        assert_eq!(slots.open_at(slot, ip(slot), false, 10), Admit::Serve(None));
        slots.touch_at(slot, 10);
    }
    assert_eq!(slots.open_at(8, [192, 168, 0, 11], true, 11), Admit::Serve(Some(1)), "not the idle master");
}

/// One source at its limit: its own idlest connection makes room, unless all of them are in
/// an exchange, when its newcomer goes.
#[test]
fn a_source_at_its_limit_closes_its_own_idle_connection_or_its_newcomer() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    let one = [10, 0, 0, 1];
    for slot in 0..PER_SOURCE {
        assert_eq!(slots.open_at(slot, one, false, 0), Admit::Serve(None));
        slots.touch_at(slot, 0);
    }
    assert_eq!(slots.open_at(4, one, false, 1), Admit::Wait, "its four are all in an exchange");
    slots.answered(2);
    assert_eq!(slots.admit_at(4, 2), Admit::Serve(Some(2)));
    slots.close(2);
    assert_eq!(slots.open_at(5, [10, 0, 0, 2], false, 3), Admit::Serve(None), "another source has room");
}

#[test]
fn slots_evict_the_longest_idle() {
    // Past the half-second grace of a connection not heard from yet.
    let slots = Slots::<NoopRawMutex, 3>::new(2, PER_SOURCE);
    assert_eq!(slots.open_at(0, ip(0), false, 0), Admit::Serve(None));
    assert_eq!(slots.open_at(1, ip(1), false, 1000), Admit::Serve(None));
    slots.touch_at(0, 1500); // slot 1 is now the longest idle
    slots.answered(0);
    assert_eq!(slots.open_at(2, ip(2), false, 2000), Admit::Serve(Some(1)));
    assert_eq!(slots.active(), 2);
    slots.close(1); // the evicted task closing does not disturb the count
    assert_eq!(slots.active(), 2);
}

/// A flood opens connections faster than any clock ticks: the order of opening still decides
/// which of them is idle the longest, whatever its slot number.
#[test]
fn slots_opened_in_one_tick_evict_in_the_order_they_opened() {
    let slots = Slots::<NoopRawMutex, 10>::new(8, PER_SOURCE);
    let order = [9, 4, 0, 7, 2, 5, 8, 1];
    for slot in order {
        assert_eq!(slots.open_at(slot, ip(slot), false, 0), Admit::Serve(None));
    }
    // A second later (none heard from, all past their grace) slots 3 and 6 open in one tick,
    // each closing the one opened first of the rest.
    assert_eq!(slots.open_at(3, ip(3), false, 1000), Admit::Serve(Some(9)));
    assert_eq!(slots.open_at(6, ip(6), false, 1000), Admit::Serve(Some(4)));
    // Slot 0 receives a request and is answered: 7 is now the one idle longest; 3 and 6, just
    // opened, are in their grace.
    slots.touch_at(0, 1000);
    slots.answered(0);
    assert_eq!(slots.open_at(9, ip(9), false, 1000), Admit::Serve(Some(7)));
    assert_eq!(slots.open_at(4, ip(4), false, 1000), Admit::Serve(Some(2)));
    assert_eq!(slots.open_at(7, ip(7), false, 1000), Admit::Serve(Some(5)));
    assert_eq!(slots.active(), 8);
}

/// A peer that sends one request and then never reads: every write waits forever.
struct Stalled(Option<Vec<u8>>);

impl embedded_io_async::ErrorType for Stalled {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Read for Stalled {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        match self.0.take() {
            Some(frame) => {
                buf[..frame.len()].copy_from_slice(&frame);
                Ok(frame.len())
            }
            None => core::future::pending().await,
        }
    }
}

impl embedded_io_async::Write for Stalled {
    async fn write(&mut self, _: &[u8]) -> Result<usize, Self::Error> {
        core::future::pending().await
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        core::future::pending().await
    }
}

#[test]
fn a_peer_that_stops_reading_is_still_evicted() {
    // Its answer cannot be sent (a zero window); when a newcomer needs the slot (after the
    // half second a request in progress is kept), the connection ends anyway instead of
    // holding its task.
    use std::future::Future;
    use std::task::{Context, Poll, Waker};
    let map = Mutex::<NoopRawMutex, _>::new(TestMap::default());
    let slots = Slots::<NoopRawMutex, 2>::new(1, PER_SOURCE);
    let mut io = Stalled(Some(hex("00 01 00 00 00 06 01 03 00 00 00 01")));
    let mut server = std::pin::pin!(serve(&mut io, [127, 0, 0, 1], &map, &slots, 0));
    let mut cx = Context::from_waker(Waker::noop());
    // Before the request is received: the request's exchange starts at or after `now`.
    let now = embassy_time::Instant::now().as_millis();
    assert!(server.as_mut().poll(&mut cx).is_pending(), "stuck sending the answer");
    assert_eq!(slots.open_at(1, ip(1), false, now), Admit::Wait, "its request is recent: the newcomer waits");
    assert!(server.as_mut().poll(&mut cx).is_pending(), "still sending");
    assert_eq!(slots.admit_at(1, now + GRACE_MS + 10), Admit::Serve(Some(0)), "the newcomer evicts it");
    assert_eq!(server.as_mut().poll(&mut cx), Poll::Ready(Ended::Evicted));
}
