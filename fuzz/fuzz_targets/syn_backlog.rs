//! The Modbus port's SYN backlog (shared::backlog), fed what any peer on the LAN can send,
//! against a model of the frames it holds. The input is a list of operations: a frame arrives
//! (arbitrary bytes, or well-formed SYNs to the Modbus port from 80 clients, one or a flood), a
//! connection task listens, a task accepts (a client, or fails), the clock moves on, the stack
//! takes the next held SYN. Invariants: nothing panics; only a SYN to the port is ever held, at
//! most HELD of them, one per client; the held count is the model's (a full backlog drops its
//! oldest, a SYN held for HOLD_MS is dropped); a released frame is the oldest held SYN, byte
//! for byte, released before HOLD_MS; a release needs a listening task.
//! `cargo +nightly fuzz run syn_backlog` (from the repository root).
#![no_main]

use std::collections::VecDeque;

use libfuzzer_sys::fuzz_target;
use remodaq_shared::backlog::{syn_to, Backlog, Peer, Verdict, HELD, HOLD_MS, MAX_SYN_FRAME};
use remodaq_shared::modbus::server::SOCKETS;

const PORT: u16 = 8000;

/// A SYN from 10.0.0.`client`:(4000 + `client`) to the Modbus port (RFC 791 and RFC 9293
/// layouts, no options).
fn syn(client: u8) -> Vec<u8> {
    let mut f = vec![2, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0, 2, 0x08, 0x00];
    f.extend_from_slice(&[0x45, 0, 0, 40, 0, 0, 0x40, 0, 64, 6, 0, 0, 10, 0, 0, client, 10, 0, 0, 15]);
    f.extend_from_slice(&(4000 + u16::from(client)).to_be_bytes());
    f.extend_from_slice(&PORT.to_be_bytes());
    f.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 0, 0x50, 0x02, 0xFA, 0xF0, 0, 0, 0, 0]);
    f
}

fn client(n: u8) -> Peer {
    Peer { ip: [10, 0, 0, n], port: 4000 + u16::from(n) }
}

/// The model: the SYNs held, oldest first, each with its client and arrival time.
#[derive(Default)]
struct Model {
    held: VecDeque<(Peer, Vec<u8>, u64)>,
}

impl Model {
    fn expire(&mut self, now: u64) {
        self.held.retain(|&(_, _, at)| now - at < HOLD_MS);
    }

    /// `frame` arrived at `now` and the backlog answered `verdict`.
    fn arrived(&mut self, backlog: &Backlog, frame: &[u8], now: u64, verdict: Verdict) {
        let Some(peer) = syn_to(frame, PORT) else {
            assert_eq!(verdict, Verdict::Pass, "only a SYN to the port is held");
            return;
        };
        self.expire(now);
        if verdict == Verdict::Hold && !self.held.iter().any(|(p, _, _)| *p == peer) {
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
    let mut backlog = Backlog::new();
    let mut model = Model::default();
    let mut now = 0u64;
    let mut accepting = 0usize;
    let mut out = [0u8; MAX_SYN_FRAME];
    let mut ops = data;
    // At most one flood an input, so that an input stays cheap.
    let mut flooded = false;
    while let Some((&op, rest)) = ops.split_first() {
        ops = rest;
        let arg = op / 6;
        match op % 6 {
            0 => {
                // Arbitrary bytes: a length, then that many bytes.
                let Some((&len, rest)) = ops.split_first() else { return };
                let (frame, rest) = rest.split_at(usize::from(len).min(rest.len()));
                ops = rest;
                let verdict = backlog.arrive(frame, now);
                if accepting == 0 && model.held.is_empty() {
                    // No task has ever listened: the port is not known yet.
                    if backlog.held() == 0 {
                        assert_eq!(verdict, Verdict::Pass, "held before any task listened");
                        continue;
                    }
                }
                model.arrived(&backlog, frame, now, verdict);
            }
            1 => {
                // The next byte: below 80, one of 80 clients (more than the backlog holds);
                // above, a flood of 66 from consecutive clients (once an input at most): two more than
                // the backlog holds.
                let Some((&n, rest)) = ops.split_first() else { return };
                ops = rest;
                let clients = if n < 80 || flooded { n..n + 1 } else { n..n + 66 };
                flooded |= clients.len() > 1;
                for c in clients {
                    let frame = syn(c % 80);
                    let verdict = backlog.arrive(&frame, now);
                    model.arrived(&backlog, &frame, now, verdict);
                }
            }
            2 if accepting < SOCKETS => {
                backlog.listening(PORT);
                accepting += 1;
            }
            3 if accepting > 0 => {
                // One of the first 42 clients, or none (an accept that failed).
                backlog.accepted((arg < 42).then(|| client(arg)));
                accepting -= 1;
            }
            4 => now += u64::from(arg) * 25,
            5 => {
                model.expire(now);
                if let Some(len) = backlog.release(now, &mut out) {
                    assert!(accepting > 0, "released with no task listening");
                    let (peer, frame, at) = model.held.pop_front().expect("released only what was held");
                    assert_eq!(&out[..len], &frame[..], "released in arrival order");
                    assert_eq!(syn_to(&out[..len], PORT), Some(peer));
                    assert!(now - at < HOLD_MS);
                }
                if !model.held.is_empty() || backlog.held() > 0 {
                    assert_eq!(backlog.held(), model.held.len(), "held count after a release");
                }
            }
            _ => {}
        }
        assert!(backlog.held() <= HELD);
    }
});
