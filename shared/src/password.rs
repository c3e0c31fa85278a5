//! The configuration password on the module (docs/security.md): the stored [`Credential`]
//! (never the password), the module's random numbers ([`AUTH`]: nonces, key-agreement keys)
//! and the module-wide guessing [`Budget`] that the discovery service and the update service
//! share, whatever source addresses the guesses claim.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use remodaq_protocol::auth::{hmac, verify_proof};
pub use remodaq_protocol::auth::{Credential, CREDENTIAL_LEN, KEY_LEN, NONCE_LEN};

use crate::settings::{RecordReader, RecordWriter};

/// The settings tag of the credential (tags: 1-4 network, 5-6 the old hash, 7 the allow-list, 9
/// the update counters; `settings_round_trip` tests check none collide). (Tags 5 and 6 held the salted SHA-256 hash of settings
/// version 1: a hash cannot be turned into SCRAM keys, so such a record loads with the factory
/// credential, which the module then reports: docs/security.md, "Migration".)
const TAG_CREDENTIAL: u8 = 8;

/// Writes the credential into a settings record.
pub fn encode(c: &Credential, w: &mut RecordWriter<'_>) {
    w.put(TAG_CREDENTIAL, &c.encode());
}

/// A credential no proof matches (its StoredKey is no SHA-256 anyone can invert): what a
/// record of settings version 2 or later whose credential is missing or damaged loads as. The
/// module then fails closed: no authenticated command works until the USER button's factory
/// reset, where falling back to the factory password would hand the module to anyone.
pub const LOCKED: Credential =
    Credential { salt: [0; 16], iterations: 4096, stored_key: [0; KEY_LEN], server_key: [0; KEY_LEN] };

/// The credential of a settings record of schema `version`: a record of version 1 (a salted
/// hash, before credentials) loads with the factory one (docs/security.md, "Migration"); a
/// later record without a usable credential loads [`LOCKED`].
pub fn decode(version: u8, r: &RecordReader<'_>) -> Credential {
    match r.array::<CREDENTIAL_LEN>(TAG_CREDENTIAL).map(|b| Credential::decode(&b)) {
        Some(c) if c.is_acceptable() => c,
        _ if version < 2 => Credential::FACTORY,
        _ => {
            crate::error!("settings: the password's credential is damaged: locked until a factory reset");
            LOCKED
        }
    }
}

/// Failed proofs the whole module allows in a burst.
pub const BUDGET: u32 = 10;
/// One failed proof more is allowed every this many ms (10 a minute, sustained).
pub const REFILL_MS: u64 = 6_000;
/// Of the budget, what one source address may spend in a burst (so one host guessing leaves
/// the rest to others, extensions §4); it gets one back every `2 * REFILL_MS`.
pub const SOURCE_BUDGET: u32 = 5;
/// Source addresses remembered for their share (the least recently seen is forgotten first).
pub const SOURCES: usize = 16;

/// A token bucket kept as the time at which it is full again (GCRA).
#[derive(Clone, Copy, Default)]
struct Bucket {
    full_at_ms: u64,
}

impl Bucket {
    /// Whether one token is left at `now_ms` in a bucket of `capacity` refilled every
    /// `refill_ms`.
    fn has_token(&self, now_ms: u64, capacity: u32, refill_ms: u64) -> bool {
        let debt = self.full_at_ms.saturating_sub(now_ms);
        debt + refill_ms <= u64::from(capacity) * refill_ms
    }
    fn take(&mut self, now_ms: u64, refill_ms: u64) {
        self.full_at_ms = self.full_at_ms.max(now_ms) + refill_ms;
    }
}

#[derive(Clone, Copy)]
struct Source {
    ip: [u8; 4],
    bucket: Bucket,
    last_ms: u64,
}

/// The module-wide guessing budget: at most [`BUDGET`] failed proofs in a burst and one more
/// every [`REFILL_MS`] (10 a minute) for the whole module, and at most [`SOURCE_BUDGET`] of
/// them from one source address. A proof is not checked at all while the budget (or its
/// source's share) is spent. A forged source can thus delay the administrator, but once it
/// stops, the module takes proofs again within 6 s (the whole budget is back within a minute):
/// there is no lock-out longer than the budget window.
#[derive(Default)]
pub struct Budget {
    module: Bucket,
    sources: [Option<Source>; SOURCES],
}

impl Budget {
    /// Whether a proof from `from` may be checked at `now_ms`.
    pub fn allows(&self, from: [u8; 4], now_ms: u64) -> bool {
        let source = self.sources.iter().flatten().find(|s| s.ip == from);
        self.module.has_token(now_ms, BUDGET, REFILL_MS)
            && source.is_none_or(|s| s.bucket.has_token(now_ms, SOURCE_BUDGET, 2 * REFILL_MS))
    }

    /// A proof from `from` failed at `now_ms`: it costs one token of the module and of its
    /// source.
    pub fn failed(&mut self, from: [u8; 4], now_ms: u64) {
        self.module.take(now_ms, REFILL_MS);
        let slot = match self.sources.iter().position(|s| s.is_some_and(|s| s.ip == from)) {
            Some(i) => i,
            None => {
                let oldest = (0..SOURCES).min_by_key(|&i| self.sources[i].map_or(0, |s| s.last_ms)).unwrap_or(0);
                self.sources[oldest] = None;
                oldest
            }
        };
        let source = self.sources[slot].get_or_insert(Source { ip: from, bucket: Bucket::default(), last_ms: 0 });
        source.last_ms = now_ms;
        source.bucket.take(now_ms, 2 * REFILL_MS);
    }
}

/// A deterministic random bit generator (HMAC-SHA-256 in counter mode, after HMAC-DRBG's
/// update step), seeded by the board's entropy at start-up and stirred with the time of every
/// request that asks for a nonce.
struct Drbg {
    key: [u8; KEY_LEN],
    counter: u64,
}

impl Drbg {
    fn stir(&mut self, data: &[u8]) {
        self.key = hmac(&self.key, &[b"stir", &self.counter.to_le_bytes(), data]);
    }
    fn fill(&mut self, out: &mut [u8]) {
        for chunk in out.chunks_mut(KEY_LEN) {
            self.counter += 1;
            let block = hmac(&self.key, &[b"out", &self.counter.to_le_bytes()]);
            chunk.copy_from_slice(&block[..chunk.len()]);
        }
        // Forward secrecy of what was handed out: the key moves on.
        self.stir(b"next");
    }
}

/// The module-wide state of authentication.
struct State {
    drbg: Drbg,
    budget: Budget,
    seeded: bool,
}

/// Authentication state shared by the discovery and the update services.
pub struct Authority {
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
}

/// The module's authentication state.
pub static AUTH: Authority = Authority::new();

/// The outcome of checking a proof.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Check {
    /// Right: the ClientKey of the session (the key that sealed a new credential's context).
    Ok([u8; KEY_LEN]),
    /// Wrong (one failure counted against the budget).
    Wrong,
    /// Not checked: the budget is spent.
    Limited,
}

impl Authority {
    /// Unseeded.
    pub const fn new() -> Self {
        Self {
            state: Mutex::new(RefCell::new(State {
                drbg: Drbg { key: [0; KEY_LEN], counter: 0 },
                budget: Budget { module: Bucket { full_at_ms: 0 }, sources: [None; SOURCES] },
                seeded: false,
            })),
        }
    }

    /// Seeds the random numbers with the board's entropy (at start-up).
    pub fn seed(&self, entropy: &[u8; 32]) {
        self.state.lock(|s| {
            let mut s = s.borrow_mut();
            s.drbg.stir(entropy);
            s.seeded = true;
        });
    }

    /// Whether the board seeded the random numbers (the web console hands out no challenge
    /// before: its nonces would be predictable).
    pub fn is_seeded(&self) -> bool {
        self.state.lock(|s| s.borrow().seeded)
    }

    /// Forgets every failed proof (tests that share the module's static run one at a time).
    #[doc(hidden)]
    pub fn reset_budget_for_tests(&self) {
        self.state.lock(|s| s.borrow_mut().budget = Budget::default());
    }

    /// Fresh random bytes, stirred first with `context` (e.g. the time and source of a request).
    pub fn random(&self, context: &[u8], out: &mut [u8]) {
        self.state.lock(|s| {
            let mut s = s.borrow_mut();
            if !s.seeded {
                crate::warn!("auth: random numbers before the board seeded them");
            }
            s.drbg.stir(context);
            s.drbg.fill(out);
        });
    }

    /// Checks `proof` over `message` against `credential`, for a request from `from` at
    /// `now_ms`, within the module-wide budget; counts the security events.
    pub fn check(
        &self,
        credential: &Credential,
        message: &[&[u8]],
        proof: &[u8; KEY_LEN],
        from: [u8; 4],
        now_ms: u64,
    ) -> Check {
        let allowed = self.state.lock(|s| s.borrow().budget.allows(from, now_ms));
        if !allowed {
            crate::diagnostics::DIAGNOSTICS.security(crate::diagnostics::Security::BudgetRefusal, from);
            return Check::Limited;
        }
        match verify_proof(&credential.stored_key, message, proof) {
            Some(client_key) => Check::Ok(client_key),
            None => {
                self.state.lock(|s| s.borrow_mut().budget.failed(from, now_ms));
                crate::diagnostics::DIAGNOSTICS.security(crate::diagnostics::Security::AuthFailure, from);
                crate::warn!("auth: a wrong proof");
                Check::Wrong
            }
        }
    }
}

impl Default for Authority {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budget_is_module_wide_with_a_share_per_source() {
        let mut b = Budget::default();
        let (guesser, admin) = ([10, 0, 0, 66], [10, 0, 0, 1]);
        // One source spends its share of 5, then waits; others still have the rest.
        for _ in 0..5 {
            assert!(b.allows(guesser, 0));
            b.failed(guesser, 0);
        }
        assert!(!b.allows(guesser, 0), "a source's share is 5");
        assert!(b.allows(admin, 0), "the administrator still gets checked");
        // Forged sources, one guess each: the module-wide budget of 10 ends it.
        for i in 0..5u8 {
            assert!(b.allows([10, 1, 0, i], 0));
            b.failed([10, 1, 0, i], 0);
        }
        assert!(!b.allows([10, 2, 0, 0], 0) && !b.allows(admin, 0), "10 failed proofs: nothing more is checked");
        // One token back every 6 s: 10 a minute at most.
        assert!(!b.allows(admin, 5_999));
        assert!(b.allows(admin, 6_000));
        b.failed([10, 3, 0, 0], 6_000);
        assert!(!b.allows(admin, 6_000));
        // Once the guessing stops, the whole budget is back within a minute.
        for i in 0..10u8 {
            assert!(b.allows([10, 4, 0, i], 66_000), "guess {i}");
            b.failed([10, 4, 0, i], 66_000);
        }
        assert!(!b.allows(admin, 66_000));
    }

    #[test]
    fn random_numbers_differ() {
        let a = Authority::new();
        a.seed(&[1; 32]);
        let (mut x, mut y) = ([0u8; 16], [0u8; 16]);
        a.random(b"t=1", &mut x);
        a.random(b"t=1", &mut y);
        assert_ne!(x, y, "the same context twice still gives new bytes");
        let b = Authority::new();
        b.seed(&[2; 32]);
        let mut z = [0u8; 16];
        b.random(b"t=1", &mut z);
        assert_ne!(x, z, "another seed, other bytes");
    }
}
