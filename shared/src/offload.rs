//! Long computations off the main executor (docs/design.md, "Three executors"): a login's or a
//! password change's key agreement (X25519, about 4 ms on the M4 under QEMU), an update's
//! signature check (ed25519, about 6 ms), which held every task of the main executor (the Modbus
//! server's among them) for as long. A service hands [`run`] a function and the bytes it works
//! on; on the target boards [`work`], a task of the background executor that every other task
//! preempts, computes it, and the service's task waits without holding anything.
//!
//! The job owns its bytes (copied in, copied back): a waiting task that is dropped (its
//! connection's deadline) leaves nothing borrowed behind, and its job's result, numbered, is
//! never taken for the next one's. One job at a time; the others wait their turn. Without a
//! worker (the host build, the tests) [`run`] computes at once, as before.
//!
//! A key pair for a key agreement ([`key_pair`]: a password change's, discovery's) is made by the
//! worker ahead of the request, so that taking it is no await at all.

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex as Cs;
use embassy_sync::blocking_mutex::Mutex as Blocking;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use remodaq_protocol::auth::{BASE_POINT, KEY_LEN};

use crate::password::AUTH;

/// The bytes a job works on: its inputs, then its result (an update's check: the header, 146
/// bytes, the digest and the key).
pub const BYTES: usize = 256;

/// A job's bytes.
pub type Bytes = [u8; BYTES];

/// A computation on a job's bytes, in place.
pub type Work = fn(&mut Bytes);

/// Whether [`work`] runs.
static RUNNING: AtomicBool = AtomicBool::new(false);
/// The job asked for: its number, what to compute, on what.
static REQUEST: Signal<Cs, (u32, Work, Bytes)> = Signal::new();
/// The job done: its number and its bytes.
static DONE: Signal<Cs, (u32, Bytes)> = Signal::new();
/// One job at a time.
static TURN: Mutex<Cs, ()> = Mutex::new(());
/// The last job's number.
static NUMBER: AtomicU32 = AtomicU32::new(0);

/// `work` on `bytes`, by the worker if one runs (the caller waits), else here and now.
pub async fn run(work: Work, mut bytes: Bytes) -> Bytes {
    if !RUNNING.load(Ordering::Acquire) {
        work(&mut bytes);
        return bytes;
    }
    let _turn = TURN.lock().await;
    let number = NUMBER.fetch_add(1, Ordering::Relaxed).wrapping_add(1);
    DONE.reset();
    REQUEST.signal((number, work, bytes));
    loop {
        // A job of a waiter that was dropped may end first: not this one's.
        let (done, bytes) = DONE.wait().await;
        if done == number {
            return bytes;
        }
    }
}

/// The worker: computes the jobs [`run`] hands it, and a key pair ahead when one is asked
/// for ([`key_pair`]), forever. A task of the board's background executor (boards/image.rs),
/// spawned before the services start.
pub async fn work() -> ! {
    RUNNING.store(true, Ordering::Release);
    loop {
        match select(REQUEST.wait(), WANT_SPARE.wait()).await {
            Either::First((number, work, mut bytes)) => {
                work(&mut bytes);
                DONE.signal((number, bytes));
            }
            Either::Second(()) => {
                if SPARE.lock(|s| s.get().is_none()) {
                    let pair = make_key_pair(&embassy_time::Instant::now().as_ticks().to_le_bytes());
                    SPARE.lock(|s| s.set(Some(pair)));
                }
            }
        }
    }
}

/// An X25519 key pair: the secret scalar and its public key.
pub type KeyPair = ([u8; KEY_LEN], [u8; KEY_LEN]);

/// The key pair the worker made ahead, until taken.
static SPARE: Blocking<Cs, Cell<Option<KeyPair>>> = Blocking::new(Cell::new(None));
/// Asks the worker for a key pair ahead.
static WANT_SPARE: Signal<Cs, ()> = Signal::new();

/// A fresh key pair for one key agreement (a password change's, discovery's): the one the
/// worker made ahead, and another asked for at once; made here when none is ready (no worker,
/// or two asked in a row). Made ahead, a password change's key costs the main executor nothing
/// and its request no await (each await of the web console's router is flash: docs/web.md).
pub fn key_pair(context: &[u8]) -> KeyPair {
    let spare = SPARE.lock(Cell::take);
    WANT_SPARE.signal(());
    spare.unwrap_or_else(|| make_key_pair(context))
}

/// Asks the worker for a key pair ahead: a service at its start, once the board has seeded the
/// module's random numbers.
pub fn prepare_key_pair() {
    WANT_SPARE.signal(());
}

/// A secret from the module's random numbers (`context` stirred in) and its public key.
fn make_key_pair(context: &[u8]) -> KeyPair {
    let mut secret = [0u8; KEY_LEN];
    AUTH.random(context, &mut secret);
    (secret, remodaq_protocol::auth::x25519(&secret, &BASE_POINT))
}

/// [`remodaq_protocol::auth::x25519`] by the worker: `scalar` times the point `u`.
pub async fn x25519(scalar: &[u8; KEY_LEN], u: &[u8; KEY_LEN]) -> [u8; KEY_LEN] {
    fn compute(bytes: &mut Bytes) {
        let (mut scalar, mut u) = ([0u8; KEY_LEN], [0u8; KEY_LEN]);
        scalar.copy_from_slice(&bytes[..KEY_LEN]);
        u.copy_from_slice(&bytes[KEY_LEN..2 * KEY_LEN]);
        // The result in place of the scalar, which is not handed back.
        bytes[..2 * KEY_LEN].fill(0);
        bytes[..KEY_LEN].copy_from_slice(&remodaq_protocol::auth::x25519(&scalar, &u));
    }
    let mut bytes = [0u8; BYTES];
    bytes[..KEY_LEN].copy_from_slice(scalar);
    bytes[KEY_LEN..2 * KEY_LEN].copy_from_slice(u);
    let done = run(compute, bytes).await;
    let mut result = [0u8; KEY_LEN];
    result.copy_from_slice(&done[..KEY_LEN]);
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::future::Future;

    fn double(bytes: &mut Bytes) {
        for b in bytes.iter_mut() {
            *b = b.wrapping_mul(2);
        }
    }

    fn bytes(first: u8) -> Bytes {
        let mut b = [0u8; BYTES];
        b[0] = first;
        b[BYTES - 1] = first;
        b
    }

    /// Without a worker the job is computed at once; with one (on a thread of its own, as the
    /// background executor is to the main one), by it: the same bytes either way, and a job of
    /// a waiter dropped before its end is never taken for the next.
    #[test]
    fn jobs_are_computed_with_or_without_the_worker() {
        let direct = embassy_futures::block_on(run(double, bytes(21)));
        assert_eq!((direct[0], direct[BYTES - 1]), (42, 42));

        std::thread::spawn(|| embassy_futures::block_on(work()));
        while !RUNNING.load(Ordering::Acquire) {
            std::thread::yield_now();
        }
        // A waiter dropped once its job was asked for.
        {
            let mut dropped = core::pin::pin!(run(double, bytes(1)));
            let waker = core::task::Waker::noop();
            let _ = dropped.as_mut().poll(&mut core::task::Context::from_waker(waker));
        }
        for n in 2..50u8 {
            let done = embassy_futures::block_on(run(double, bytes(n)));
            assert_eq!((done[0], done[BYTES - 1]), (2 * n, 2 * n), "job {n}");
        }
        // RFC 7748 §6.1: Alice's public key from her private key, by the worker.
        let hex = |s: &str| -> [u8; KEY_LEN] {
            core::array::from_fn(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        };
        let alice = hex("77076d0a7318a57d3c16c17251b26645df4c2f87ebc0992ab177fba51db92c2a");
        let public = embassy_futures::block_on(x25519(&alice, &remodaq_protocol::auth::BASE_POINT));
        assert_eq!(public, hex("8520f0098930a754748b7ddcb43ef75a0dbf3a0d26381af4eba4a98eaa9b4e6a"));

        // Key pairs made ahead by the worker: each a pair (two agree on one secret, RFC 7748
        // §6.1's property), none given twice.
        prepare_key_pair();
        while SPARE.lock(|s| s.get().is_none()) {
            std::thread::yield_now();
        }
        let (a, b) = (key_pair(b"a"), key_pair(b"b"));
        assert_ne!(a, b);
        let ab = embassy_futures::block_on(x25519(&a.0, &b.1));
        assert_eq!(ab, embassy_futures::block_on(x25519(&b.0, &a.1)));
    }
}
