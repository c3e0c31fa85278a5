//! The backlog's tests: the frame checks, the queue, and the gates behind the driver wrapper.

use super::*;
use core::task::{Context, Waker};
use std::vec::Vec as StdVec;

const PORT: u16 = 8000;

/// An Ethernet II frame with an IPv4 header (no options) and a TCP header with `options`
/// bytes of options, from 10.0.2.2:`from` to 10.0.2.15:`to`, with TCP `flags`. Laid out by
/// hand from RFC 791 §3.1 and RFC 9293 §3.1 (checksums left 0: the backlog reads none).
fn segment(from: u16, to: u16, flags: u8, options: usize) -> StdVec<u8> {
    let tcp_len = 20 + options;
    let total = 20 + tcp_len;
    let mut f = StdVec::new();
    f.extend_from_slice(&[0x02, 0, 0, 0, 0, 0x15, 0x52, 0x55, 10, 0, 2, 2, 0x08, 0x00]);
    f.extend_from_slice(&[0x45, 0, (total >> 8) as u8, total as u8, 0, 1, 0x40, 0, 64, 6, 0, 0]);
    f.extend_from_slice(&[10, 0, 2, 2, 10, 0, 2, 15]);
    f.extend_from_slice(&from.to_be_bytes());
    f.extend_from_slice(&to.to_be_bytes());
    f.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 0, ((tcp_len / 4) << 4) as u8, flags, 0xFA, 0xF0, 0, 0, 0, 0]);
    f.resize(14 + total, 1); // option bytes: NOP (1)
    f
}

const SYN: u8 = 0x02;

fn syn(from: u16) -> StdVec<u8> {
    segment(from, PORT, SYN, 20)
}

fn peer(port: u16) -> Peer {
    Peer { ip: [10, 0, 2, 2], port }
}

#[test]
fn recognises_only_a_connection_request_to_the_port() {
    assert_eq!(syn_to(&syn(40000), PORT), Some(peer(40000)));
    assert_eq!(syn_to(&segment(40000, PORT, SYN, 0), PORT), Some(peer(40000)));
    // SYN-ACK, ACK, RST+SYN, SYN+FIN, FIN, another port: not a request to the Modbus port.
    for flags in [0x12, 0x10, 0x06, 0x03, 0x01, 0x18] {
        assert_eq!(syn_to(&segment(40000, PORT, flags, 0), PORT), None, "flags {flags:02x}");
    }
    assert_eq!(syn_to(&segment(40000, 8301, SYN, 0), PORT), None);
    // UDP (protocol 17), IPv6 EtherType, IPv4 with version 6, a later fragment.
    let mut udp = syn(40000);
    udp[14 + 9] = 17;
    assert_eq!(syn_to(&udp, PORT), None);
    let mut v6 = syn(40000);
    v6[12..14].copy_from_slice(&[0x86, 0xDD]);
    assert_eq!(syn_to(&v6, PORT), None);
    let mut bad_version = syn(40000);
    bad_version[14] = 0x65;
    assert_eq!(syn_to(&bad_version, PORT), None);
    let mut fragment = syn(40000);
    fragment[14 + 6..14 + 8].copy_from_slice(&[0x20, 0x00]); // more fragments
    assert_eq!(syn_to(&fragment, PORT), None);
}

#[test]
fn a_segment_says_its_ports_flags_and_data_length() {
    // A Modbus request of 12 bytes (MBAP 7 + function 1 + 4) with PSH+ACK, after 12 bytes of
    // TCP options (timestamps): IPv4 total length 20 + 32 + 12.
    let mut request = segment(40000, PORT, 0x18, 12);
    request.extend_from_slice(&[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 1]);
    request[16..18].copy_from_slice(&64u16.to_be_bytes());
    let expected = Segment { source: 40000, destination: PORT, flags: 0x18, data: 12 };
    assert_eq!(tcp_segment(&request), Some(expected));
    assert!(!expected.ends());
    // An answer's FIN without data; an RST.
    let fin = tcp_segment(&segment(PORT, 40000, 0x11, 0));
    assert_eq!(fin.map(|s| (s.source, s.data, s.ends())), Some((PORT, 0, true)));
    assert_eq!(tcp_segment(&segment(PORT, 40000, 0x04, 0)).map(|s| s.ends()), Some(true));
    // A total length shorter than its own headers is no segment; UDP neither.
    let mut short = segment(40000, PORT, 0x10, 0);
    short[16..18].copy_from_slice(&30u16.to_be_bytes());
    assert_eq!(tcp_segment(&short), None);
    let mut udp = segment(40000, PORT, 0x10, 0);
    udp[14 + 9] = 17;
    assert_eq!(tcp_segment(&udp), None);
}

#[test]
fn an_ip_header_with_options_moves_the_tcp_header() {
    // IHL 6: four option bytes (NOP x4) before TCP.
    let plain = segment(40001, PORT, SYN, 0);
    let mut f = plain[..34].to_vec();
    f[14] = 0x46;
    f.extend_from_slice(&[1, 1, 1, 1]);
    f.extend_from_slice(&plain[34..]);
    assert_eq!(syn_to(&f, PORT), Some(peer(40001)));
}

/// A SYN from 10.0.2.2:40000 to 10.0.2.15:8000 (MAC 02:00:00:00:00:15) with both checksums
/// right, computed independently (Python, RFC 1071).
const GOOD_SYN: &str = "02 00 00 00 00 15 52 55 0a 00 02 02 08 00 45 00 00 28 00 01 40 00 40 06 22 bf \
    0a 00 02 02 0a 00 02 0f 9c 40 1f 40 00 00 00 01 00 00 00 00 50 02 fa f0 e1 5f 00 00";
const MY_MAC: [u8; 6] = [0x02, 0, 0, 0, 0, 0x15];
const MY_IP: [u8; 4] = [10, 0, 2, 15];

fn good_syn() -> StdVec<u8> {
    GOOD_SYN.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

#[test]
fn only_intact_syns_for_this_module_take_a_listener() {
    let good = good_syn();
    assert!(for_me(&good, &MY_MAC, &MY_IP));
    let mut good_with_fcs = good.clone();
    good_with_fcs.extend_from_slice(&[0xDE, 0xAD, 0xBE, 0xEF]);
    assert!(for_me(&good_with_fcs, &MY_MAC, &MY_IP), "the frame check sequence after the packet");
    let junk = |at: usize| {
        let mut f = good.clone();
        f[at] ^= 0x01;
        f
    };
    // Another MAC, another destination IP, a damaged IP header, a damaged TCP segment.
    for (what, frame) in [("mac", junk(5)), ("ip", junk(33)), ("ip header", junk(22)), ("tcp", junk(49))] {
        assert!(!for_me(&frame, &MY_MAC, &MY_IP), "{what}");
        let mut b = ModbusBacklog::new();
        b.identify(MY_MAC, MY_IP, HELD_PER_SOURCE);
        b.listening(PORT);
        assert_eq!(b.arrive(&frame, 0), Verdict::Hold, "{what}: dropped");
        assert_eq!((b.held(), b.free()), (0, 1), "{what}: the listener is still free");
        assert_eq!(b.arrive(&good, 0), Verdict::Pass, "{what}: then a real client gets it");
    }
}

#[test]
fn one_source_holds_at_most_four_syns() {
    let mut b = ModbusBacklog::new();
    b.identify([0x02, 0, 0, 0, 0, 0x15], [10, 0, 2, 15], HELD_PER_SOURCE);
    b.me = None; // the hand-built frames carry no checksums
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass, "takes the one listener");
    for port in 2..20 {
        assert_eq!(b.arrive(&syn(port), 0), Verdict::Hold);
    }
    assert_eq!(b.held(), HELD_PER_SOURCE);
    // The newest ones, in order.
    b.accepted(Some(peer(1)));
    b.listening(PORT);
    let mut out = [0u8; MAX_SYN_FRAME];
    let n = b.release(0, &mut out).unwrap();
    assert_eq!(syn_to(&out[..n], PORT), Some(peer(16)));
}

#[test]
fn a_truncated_frame_is_never_a_request_and_never_panics() {
    let f = syn(40000);
    for len in 0..f.len() {
        // The TCP flags are at byte 14 + 20 + 13 = 47: anything shorter is not a SYN.
        let expected = if len > 47 { Some(peer(40000)) } else { None };
        assert_eq!(syn_to(&f[..len], PORT), expected, "length {len}");
        let mut b = ModbusBacklog::new();
        b.listening(PORT);
        let _ = b.arrive(&f[..len], 0);
    }
}

#[test]
fn a_syn_passes_while_a_task_listens_and_is_held_after() {
    let mut b = ModbusBacklog::new();
    // No task has listened yet: the port is unknown, everything passes.
    assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
    b.listening(PORT);
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(2), 0), Verdict::Pass);
    assert_eq!(b.arrive(&syn(3), 0), Verdict::Pass);
    assert_eq!(b.arrive(&syn(4), 0), Verdict::Hold);
    assert_eq!(b.arrive(&syn(5), 0), Verdict::Hold);
    // Other traffic is never held.
    assert_eq!(b.arrive(&segment(2, PORT, 0x10, 0), 0), Verdict::Pass);
    assert_eq!(b.held(), 2);
    // A SYN sent again during its handshake is dropped (its socket sends the SYN-ACK again).
    assert_eq!(b.arrive(&syn(2), 1), Verdict::Hold);
    assert_eq!(b.held(), 2);
    // A SYN already held, sent again: still one held.
    assert_eq!(b.arrive(&syn(4), 1), Verdict::Hold);
    assert_eq!(b.held(), 2);
}

#[test]
fn a_new_connection_from_a_held_port_replaces_the_held_syn() {
    // The client reused port 4 for a new connection (a new initial sequence number) while
    // its first SYN was held: the newer SYN is the one released, in the first one's place.
    let mut b = ModbusBacklog::new();
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(2), 0), Verdict::Pass);
    assert_eq!(b.arrive(&syn(4), 0), Verdict::Hold);
    assert_eq!(b.arrive(&syn(5), 0), Verdict::Hold);
    let mut again = syn(4);
    again[38..42].copy_from_slice(&[0, 0x40, 0x77, 0x01]); // another sequence number
    assert_eq!(b.arrive(&again, 1), Verdict::Hold);
    assert_eq!(b.held(), 2);
    b.accepted(Some(Peer { ip: [10, 0, 2, 2], port: 2 }));
    b.listening(PORT);
    let mut out = [0u8; MAX_SYN_FRAME];
    let n = b.release(2, &mut out).expect("port 4 first");
    assert_eq!(&out[..n], &again[..], "the newer SYN");
}

#[test]
fn held_syns_go_in_arrival_order_as_tasks_listen_again() {
    let mut b = ModbusBacklog::new();
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(10), 0), Verdict::Pass);
    for port in 11..15 {
        assert_eq!(b.arrive(&syn(port), 0), Verdict::Hold);
    }
    let mut out = [0u8; MAX_SYN_FRAME];
    assert_eq!(b.release(1, &mut out), None, "the one task is in a handshake");
    // Its handshake completes; it accepts, then listens again (an evicted task as well).
    b.accepted(Some(peer(10)));
    assert_eq!(b.release(1, &mut out), None, "no task listens");
    b.listening(PORT);
    b.listening(PORT);
    for expected in [11, 12] {
        let len = b.release(2, &mut out).expect("a task listens");
        assert_eq!(&out[..len], &syn(expected)[..]);
    }
    assert_eq!(b.release(2, &mut out), None, "both tasks are promised");
    // A SYN arriving now queues behind the held ones even when a task listens.
    b.accepted(Some(peer(11)));
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(15), 3), Verdict::Hold);
    let len = b.release(3, &mut out).expect("a task listens");
    assert_eq!(&out[..len], &syn(13)[..]);
}

#[test]
fn a_full_backlog_drops_its_oldest_syn_for_the_newcomer() {
    let mut b = ModbusBacklog::new();
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(100), 0), Verdict::Pass);
    for i in 0..HELD as u16 + 1 {
        assert_eq!(b.arrive(&syn(200 + i), 0), Verdict::Hold);
    }
    assert_eq!(b.held(), HELD);
    b.accepted(Some(peer(100)));
    b.listening(PORT);
    let mut out = [0u8; MAX_SYN_FRAME];
    let len = b.release(0, &mut out).expect("a task listens");
    assert_eq!(&out[..len], &syn(201)[..], "the oldest (200) was dropped");
    // The newcomer, last in, is still there.
    let mut last = None;
    for _ in 0..HELD {
        b.accepted(None);
        b.listening(PORT);
        b.in_flight.clear();
        if let Some(len) = b.release(0, &mut out) {
            last = Some(out[..len].to_vec());
        }
    }
    assert_eq!(last, Some(syn(200 + HELD as u16)));
}

#[test]
fn old_syns_and_stalled_handshakes_expire() {
    let mut b = ModbusBacklog::new();
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
    assert_eq!(b.arrive(&syn(2), 0), Verdict::Hold);
    assert_eq!(b.next_change(), Some(HOLD_MS), "SYN 2 lapses first");
    assert_eq!(b.arrive(&syn(3), HOLD_MS - 1), Verdict::Hold);
    let mut out = [0u8; MAX_SYN_FRAME];
    assert_eq!(b.release(HANDSHAKE_MS - 1, &mut out), None, "the one task is in a handshake");
    assert_eq!(b.held(), 0, "both SYNs were held for HOLD_MS and dropped");
    assert_eq!(b.next_change(), None);
    // The first handshake never completed: after HANDSHAKE_MS (longer than the task waits
    // for it) the task counts as listening again.
    assert_eq!(b.arrive(&syn(4), HANDSHAKE_MS - 1), Verdict::Hold);
    assert_eq!(b.next_change(), Some(HANDSHAKE_MS), "the handshake lapses before SYN 4");
    assert_eq!(b.release(HANDSHAKE_MS, &mut out), Some(syn(4).len()));
    assert_eq!(&out[..syn(4).len()], &syn(4)[..]);
}

#[test]
fn a_client_that_resets_its_handshake_frees_the_task() {
    let mut b = ModbusBacklog::new();
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
    assert_eq!(b.arrive(&syn(2), 0), Verdict::Hold);
    let mut out = [0u8; MAX_SYN_FRAME];
    assert_eq!(b.release(1, &mut out), None);
    // A RST from another client changes nothing; one from client 1 frees its task (smoltcp
    // puts the socket in SYN-RECEIVED back in LISTEN).
    assert_eq!(b.arrive(&segment(9, PORT, 0x04, 0), 1), Verdict::Pass);
    assert_eq!(b.release(1, &mut out), None);
    assert_eq!(b.arrive(&segment(1, PORT, 0x14, 0), 2), Verdict::Pass);
    assert_eq!(b.release(2, &mut out), Some(syn(2).len()));
}

#[test]
fn a_syn_too_long_to_hold_goes_to_the_stack() {
    let mut b = ModbusBacklog::new();
    b.listening(PORT);
    assert_eq!(b.arrive(&syn(1), 0), Verdict::Pass);
    // The longest TCP header (60 bytes) with a frame check sequence after it is held; a
    // frame longer than that (here TCP options beyond the limit, as IP options would make
    // it) goes to the stack.
    let mut longest = segment(2, PORT, SYN, 40);
    longest.extend_from_slice(&[0xDE, 0xAD, 0xBE, 0xEF]);
    assert_eq!(longest.len(), MAX_SYN_FRAME);
    assert_eq!(b.arrive(&longest, 0), Verdict::Hold);
    assert_eq!(b.arrive(&segment(3, PORT, SYN, 48), 0), Verdict::Pass);
    assert_eq!(b.held(), 1);
}

/// A fake driver: frames to receive, and the frames the stack sent.
struct Wire {
    inbox: std::collections::VecDeque<StdVec<u8>>,
}

struct FakeRx(StdVec<u8>);
struct FakeTx;

impl RxToken for FakeRx {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(mut self, f: F) -> R {
        f(&mut self.0)
    }
}

impl embassy_net_driver::TxToken for FakeTx {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
        f(&mut std::vec![0; len])
    }
}

use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState, RxToken};

impl Driver for Wire {
    type RxToken<'a> = FakeRx;
    type TxToken<'a> = FakeTx;
    fn receive(&mut self, _: &mut Context) -> Option<(FakeRx, FakeTx)> {
        self.inbox.pop_front().map(|f| (FakeRx(f), FakeTx))
    }
    fn transmit(&mut self, _: &mut Context) -> Option<FakeTx> {
        Some(FakeTx)
    }
    fn link_state(&mut self, _: &mut Context) -> LinkState {
        LinkState::Up
    }
    fn capabilities(&self) -> Capabilities {
        Capabilities::default()
    }
    fn hardware_address(&self) -> HardwareAddress {
        HardwareAddress::Ethernet([2, 0, 0, 0, 0, 0x15])
    }
}

/// What the stack would see: the frames it gets from the driver, in order.
/// The ISN key of the driver wrappers of these tests.
const ISN_KEY: [u8; 16] = *b"isn key of tests";

fn drain(driver: &mut Backlogged<Wire>, cx: &mut Context) -> StdVec<StdVec<u8>> {
    let mut seen = StdVec::new();
    while let Some((rx, _tx)) = driver.receive(cx) {
        rx.consume(|frame| seen.push(frame.to_vec()));
    }
    seen
}

#[test]
fn the_driver_wrapper_holds_and_releases_syns_and_wakes_the_runner() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;
    use std::task::Wake;
    struct Count(AtomicUsize);
    impl Wake for Count {
        fn wake(self: Arc<Self>) {
            self.0.fetch_add(1, Ordering::Relaxed);
        }
    }
    static GATE: ModbusGate = SynGate::new();
    static GATES: &[&dyn Gate] = &[&GATE];
    let count = Arc::new(Count(AtomicUsize::new(0)));
    let waker = Waker::from(count.clone());
    let mut cx = Context::from_waker(&waker);
    let ack = segment(9, PORT, 0x10, 0);
    let mut driver =
        Backlogged::new(Wire { inbox: [syn(1), syn(2), ack.clone(), syn(3)].into_iter().collect() }, GATES, ISN_KEY);
    GATE.listening(PORT);
    // The stack sees the first SYN and the ACK, whose acknowledgment number the wrapper moved
    // back into the stack's numbers (crate::isn); the other SYNs reach it as empty frames.
    let mut ack_seen = ack.clone();
    crate::isn::incoming(&crate::isn::IsnKey::new(ISN_KEY), &mut ack_seen);
    assert_ne!(ack_seen, ack);
    assert_eq!(drain(&mut driver, &mut cx), [syn(1), StdVec::new(), ack_seen, StdVec::new()]);
    assert_eq!(count.0.load(Ordering::Relaxed), 0);
    // A task accepts the first and another listens: the runner is woken, gets SYN 2 only.
    GATE.accepted(Some(peer(1)));
    GATE.listening(PORT);
    assert_eq!(count.0.load(Ordering::Relaxed), 1);
    assert_eq!(drain(&mut driver, &mut cx), [syn(2)]);
    GATE.accepted(Some(peer(2)));
    GATE.listening(PORT);
    assert_eq!(count.0.load(Ordering::Relaxed), 2);
    assert_eq!(drain(&mut driver, &mut cx), [syn(3)]);
}

#[test]
fn each_port_has_its_own_gate() {
    // A second port (the web console's, 80) with 2 SYNs held at most and one task.
    static MODBUS: ModbusGate = SynGate::new();
    static WEB: SynGate<2, 1> = SynGate::new();
    static BOTH: &[&dyn Gate] = &[&MODBUS, &WEB];
    let waker = Waker::noop();
    let mut cx = Context::from_waker(waker);
    let web_syn = |from| segment(from, 80, SYN, 20);
    let inbox = [syn(1), web_syn(2), web_syn(3), web_syn(4), web_syn(5), syn(6)];
    let mut driver = Backlogged::new(Wire { inbox: inbox.into_iter().collect() }, BOTH, ISN_KEY);
    MODBUS.listening(PORT);
    MODBUS.listening(PORT);
    WEB.listening(80);
    // Modbus's two SYNs and the web's first reach the stack; web SYNs 3-5 wait (the
    // backlog keeps the newest 2: 4 and 5).
    assert_eq!(drain(&mut driver, &mut cx), [syn(1), web_syn(2), StdVec::new(), StdVec::new(), StdVec::new(), syn(6)]);
    // Modbus tasks listening again release nothing of the web's.
    MODBUS.accepted(Some(peer(1)));
    MODBUS.listening(PORT);
    assert_eq!(drain(&mut driver, &mut cx), StdVec::<StdVec<u8>>::new());
    // The web task accepts 2 and listens again: 4 comes, then 5 after the next.
    WEB.accepted(Some(peer(2)));
    WEB.listening(80);
    assert_eq!(drain(&mut driver, &mut cx), [web_syn(4)]);
    WEB.accepted(Some(peer(4)));
    WEB.listening(80);
    assert_eq!(drain(&mut driver, &mut cx), [web_syn(5)]);
}

#[test]
fn two_gates_on_one_port_the_first_decides() {
    // Two services set to the same port: one gate decides for it; the other never holds a
    // SYN or counts one as promised.
    static FIRST: SynGate<2, 1> = SynGate::new();
    static SECOND: SynGate<2, 1> = SynGate::new();
    static SAME: &[&dyn Gate] = &[&FIRST, &SECOND];
    let waker = Waker::noop();
    let mut cx = Context::from_waker(waker);
    let mut driver = Backlogged::new(Wire { inbox: [syn(1), syn(2)].into_iter().collect() }, SAME, ISN_KEY);
    FIRST.listening(PORT);
    SECOND.listening(PORT);
    assert_eq!(drain(&mut driver, &mut cx), [syn(1), StdVec::new()]);
    assert_eq!(FIRST.with(|b, _| (b.held(), b.in_flight.len())), (1, 1));
    assert_eq!(SECOND.with(|b, _| (b.held(), b.in_flight.len())), (0, 0));
}
