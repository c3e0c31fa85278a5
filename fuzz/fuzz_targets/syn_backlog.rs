//! The Modbus port's SYN backlog (remodaq_net::backlog), fed what any peer on the LAN can send,
//! against a model of the frames it holds. The input is a list of operations: a frame arrives
//! (arbitrary bytes, well-formed SYNs to the Modbus port from 80 clients, one or a flood, or a
//! client's RST), a connection task listens, a task accepts (a client, or fails), the clock
//! moves on, the stack takes the next held SYN. Invariants: nothing panics; only a SYN to the port is ever held, at
//! most HELD of them, one per client; the held count is the model's (a full backlog drops its
//! oldest, a SYN held for HOLD_MS is dropped); a released frame is the oldest held SYN, byte
//! for byte, released before HOLD_MS; a release needs a listening task; the SYNs let through
//! whose handshakes are under way (until accepted, reset by the client, or HANDSHAKE_MS) never
//! outnumber the listening tasks, and a held SYN goes exactly when one is free; a SYN sent
//! again during its handshake is dropped. The arbitrary frames also go through the keyed ISNs'
//! rewriting (remodaq_net::isn), both ways: no panic, the length unchanged.
//! `cargo +nightly fuzz run syn_backlog` (from the repository root).
#![no_main]

use std::collections::VecDeque;

use libfuzzer_sys::fuzz_target;
use remodaq_modbus::server::SOCKETS;
use remodaq_net::backlog::{syn_to, ModbusBacklog, Peer, Verdict, HANDSHAKE_MS, HELD, HOLD_MS, MAX_SYN_FRAME};

const PORT: u16 = 8000;
const ISN_KEY: remodaq_net::isn::IsnKey = remodaq_net::isn::IsnKey::new(*b"fuzzing isn key!");

/// A SYN from 10.0.0.`client`:(4000 + `client`) to the Modbus port (RFC 791 and RFC 9293
/// layouts, no options).
fn syn(client: u8) -> Vec<u8> {
    segment(client, 0x02)
}

/// A segment with TCP `flags` from 10.0.0.`client`:(4000 + `client`) to the Modbus port.
fn segment(client: u8, flags: u8) -> Vec<u8> {
    let mut f = vec![2, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0, 2, 0x08, 0x00];
    f.extend_from_slice(&[0x45, 0, 0, 40, 0, 0, 0x40, 0, 64, 6, 0, 0, 10, 0, 0, client, 10, 0, 0, 15]);
    f.extend_from_slice(&(4000 + u16::from(client)).to_be_bytes());
    f.extend_from_slice(&PORT.to_be_bytes());
    f.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 0, 0x50, flags, 0xFA, 0xF0, 0, 0, 0, 0]);
    f
}

/// The client of a TCP segment to the port with RST set.
fn rst_from(frame: &[u8]) -> Option<Peer> {
    let ip = frame.get(14..)?;
    let tcp = ip.get(usize::from(ip.first()? & 0x0F) * 4..)?;
    let flags = *tcp.get(13)?;
    let to_port = u16::from_be_bytes([*tcp.get(2)?, *tcp.get(3)?]);
    let is_tcp = frame.get(12..14) == Some(&[8, 0]) && ip.get(9) == Some(&6) && ip.first()? >> 4 == 4;
    let whole = u16::from_be_bytes([*ip.get(6)?, *ip.get(7)?]) & 0x3FFF == 0 && ip.first()? & 0x0F >= 5;
    (is_tcp && whole && to_port == PORT && flags & 0x04 != 0)
        .then(|| Peer { ip: [ip[12], ip[13], ip[14], ip[15]], port: u16::from_be_bytes([tcp[0], tcp[1]]) })
}

fn client(n: u8) -> Peer {
    Peer { ip: [10, 0, 0, n], port: 4000 + u16::from(n) }
}

/// The model: the SYNs held, oldest first, each with its client and arrival time; the clients
/// whose SYN went to the stack and whose handshake is under way, and since when.
#[derive(Default)]
struct Model {
    held: VecDeque<(Peer, Vec<u8>, u64)>,
    in_flight: Vec<(Peer, u64)>,
}

impl Model {
    fn expire(&mut self, now: u64) {
        self.held.retain(|&(_, _, at)| now - at < HOLD_MS);
        self.in_flight.retain(|&(_, at)| now - at < HANDSHAKE_MS);
    }

    fn handshake(&mut self, peer: Peer, now: u64, accepting: usize) {
        self.in_flight.push((peer, now));
        assert!(self.in_flight.len() <= accepting, "more SYNs let through than tasks listen");
    }

    /// `frame` arrived at `now`, `accepting` tasks listening, and the backlog answered `verdict`.
    fn arrived(&mut self, backlog: &ModbusBacklog, frame: &[u8], now: u64, accepting: usize, verdict: Verdict) {
        let Some(peer) = syn_to(frame, PORT) else {
            assert_eq!(verdict, Verdict::Pass, "only a SYN to the port is held");
            if let Some(reset) = rst_from(frame) {
                self.in_flight.retain(|&(p, _)| p != reset);
            }
            return;
        };
        self.expire(now);
        let in_flight = self.in_flight.iter().any(|&(p, _)| p == peer);
        if in_flight {
            assert_eq!(verdict, Verdict::Hold, "a SYN sent again during its handshake is dropped");
        } else if verdict == Verdict::Pass && (frame.len() <= MAX_SYN_FRAME || self.in_flight.len() < accepting) {
            self.handshake(peer, now, accepting);
        }
        if verdict == Verdict::Hold && !in_flight && !self.held.iter().any(|(p, _, _)| *p == peer) {
            assert!(frame.len() <= MAX_SYN_FRAME, "held a frame longer than MAX_SYN_FRAME");
            if self.held.len() == HELD {
                self.held.pop_front();
            }
            self.held.push_back((peer, frame.to_vec(), now));
        }
        if verdict == Verdict::Hold || !self.held.is_empty() || backlog.held() > 0 {
            assert_eq!(backlog.held(), self.held.len(), "held count after a SYN");
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let mut backlog = ModbusBacklog::new();
    let mut model = Model::default();
    let mut now = 0u64;
    let mut accepting = 0usize;
    let mut out = [0u8; MAX_SYN_FRAME];
    let mut ops = data;
    // At most one flood an input, so that an input stays cheap.
    let mut flooded = false;
    // Whether a task ever listened (the backlog learns the port then).
    let mut listened = false;
    while let Some((&op, rest)) = ops.split_first() {
        ops = rest;
        let arg = op / 7;
        match op % 7 {
            0 => {
                // Arbitrary bytes: a length, then that many bytes.
                let Some((&len, rest)) = ops.split_first() else { return };
                let (frame, rest) = rest.split_at(usize::from(len).min(rest.len()));
                ops = rest;
                // The keyed ISNs' rewriting of the same bytes (remodaq_net::isn, on every frame
                // the embassy-net boards receive and send): never a panic, nothing added or cut.
                let mut rewritten = frame.to_vec();
                remodaq_net::isn::incoming(&ISN_KEY, &mut rewritten);
                remodaq_net::isn::outgoing(&ISN_KEY, &mut rewritten, true);
                assert_eq!(rewritten.len(), frame.len());
                let verdict = backlog.arrive(frame, now);
                if !listened {
                    assert_eq!(verdict, Verdict::Pass, "held before any task listened");
                    continue;
                }
                model.arrived(&backlog, frame, now, accepting, verdict);
            }
            1 => {
                // The next byte: below 80, one of 80 clients (more than the backlog holds);
                // above, a flood of 66 from consecutive clients (once an input at most): two more than
                // the backlog holds.
                let Some((&n, rest)) = ops.split_first() else { return };
                ops = rest;
                // In u16: a flood from client 241 runs past 255 (an overflow the fuzzer found once
                // debug assertions were on).
                let n = u16::from(n);
                let clients = if n < 80 || flooded { n..n + 1 } else { n..n + 66 };
                flooded |= clients.len() > 1;
                for c in clients {
                    let frame = syn((c % 80) as u8);
                    let verdict = backlog.arrive(&frame, now);
                    if !listened {
                        assert_eq!(verdict, Verdict::Pass, "held before any task listened");
                        continue;
                    }
                    model.arrived(&backlog, &frame, now, accepting, verdict);
                }
            }
            2 if accepting < SOCKETS => {
                backlog.listening(PORT);
                accepting += 1;
                listened = true;
            }
            3 if accepting > 0 => {
                // One of the first 32 clients, or none (an accept that failed).
                let peer = (arg < 32).then(|| client(arg));
                backlog.accepted(peer);
                accepting -= 1;
                if let Some(i) = model.in_flight.iter().position(|&(p, _)| Some(p) == peer) {
                    model.in_flight.swap_remove(i);
                }
            }
            4 => now += u64::from(arg) * 25,
            5 => {
                model.expire(now);
                let due = !model.held.is_empty() && model.in_flight.len() < accepting;
                let released = backlog.release(now, &mut out);
                assert_eq!(released.is_some(), due, "a held SYN goes exactly when a task is free");
                if let Some(len) = released {
                    assert!(accepting > 0, "released with no task listening");
                    let (peer, frame, at) = model.held.pop_front().expect("released only what was held");
                    assert_eq!(&out[..len], &frame[..], "released in arrival order");
                    assert_eq!(syn_to(&out[..len], PORT), Some(peer));
                    assert!(now - at < HOLD_MS);
                    model.handshake(peer, now, accepting);
                }
                if !model.held.is_empty() || backlog.held() > 0 {
                    assert_eq!(backlog.held(), model.held.len(), "held count after a release");
                }
            }
            6 => {
                // A client resets its connection (RST, or RST+ACK).
                // The next byte: the client, and RST+ACK from 128.
                let Some((&n, rest)) = ops.split_first() else { return };
                ops = rest;
                let frame = segment(n % 80, if n < 128 { 0x04 } else { 0x14 });
                let verdict = backlog.arrive(&frame, now);
                assert_eq!(verdict, Verdict::Pass, "a RST goes to the stack");
                if listened {
                    model.arrived(&backlog, &frame, now, accepting, verdict);
                }
            }
            _ => {}
        }
        assert!(backlog.held() <= HELD);
    }
});
