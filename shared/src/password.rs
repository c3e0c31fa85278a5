//! The configuration password: kept as a salted SHA-256 hash in the settings, checked with a
//! rate limit on wrong guesses.

use sha2::{Digest, Sha256};

use crate::settings::{RecordReader, RecordWriter};

/// Factory default configuration password.
pub const FACTORY_PASSWORD: &str = "remodaq";
/// Longest password accepted.
pub const MAX_LEN: usize = remodaq_protocol::discovery::MAX_PASSWORD_LEN;
/// Shortest new password accepted.
pub const MIN_LEN: usize = 4;

/// A salted password hash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PasswordHash {
    salt: [u8; 16],
    hash: [u8; 32],
}

mod tag {
    pub const SALT: u8 = 5;
    pub const HASH: u8 = 6;
}

fn digest(salt: &[u8; 16], password: &[u8]) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(salt);
    h.update(password);
    h.finalize().into()
}

impl PasswordHash {
    /// The hash of `password` with `salt`.
    pub fn new(salt: [u8; 16], password: &[u8]) -> Self {
        Self { salt, hash: digest(&salt, password) }
    }

    /// The factory default ([`FACTORY_PASSWORD`], zero salt).
    pub fn factory() -> Self {
        Self::new([0; 16], FACTORY_PASSWORD.as_bytes())
    }

    /// Whether `password` is the password (constant time over the hash).
    pub fn matches(&self, password: &[u8]) -> bool {
        let h = digest(&self.salt, password);
        h.iter().zip(self.hash.iter()).fold(0u8, |acc, (a, b)| acc | (a ^ b)) == 0
    }

    /// A new salt, unique per module and change: derived from the MAC, the time and the old salt.
    pub fn next_salt(&self, mac: &[u8; 6], now_ms: u64) -> [u8; 16] {
        let mut h = Sha256::new();
        h.update(mac);
        h.update(now_ms.to_le_bytes());
        h.update(self.salt);
        h.update(self.hash);
        let d: [u8; 32] = h.finalize().into();
        let mut salt = [0u8; 16];
        salt.copy_from_slice(&d[..16]);
        salt
    }

    /// Writes the fields into a settings record.
    pub fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put(tag::SALT, &self.salt);
        w.put(tag::HASH, &self.hash);
    }

    /// Reads the fields of a settings record; the factory password if absent.
    pub fn decode(r: &RecordReader<'_>) -> Self {
        match (r.array(tag::SALT), r.array(tag::HASH)) {
            (Some(salt), Some(hash)) => Self { salt, hash },
            _ => Self::factory(),
        }
    }
}

/// Wrong guesses allowed before the lock-out starts.
const FREE_FAILURES: u32 = 3;
/// Longest lock-out, ms.
const MAX_LOCKOUT_MS: u64 = 300_000;
/// Sources whose wrong guesses are remembered (extensions §4: at least the 16 most recent).
pub const SOURCES: usize = 16;

/// One source's wrong guesses.
#[derive(Clone, Copy)]
struct Source {
    ip: [u8; 4],
    failures: u32,
    locked_until_ms: u64,
    last_ms: u64,
}

/// Rate limit on password checks, kept per source address (extensions §4), so one host
/// guessing cannot lock the administrator out elsewhere: after [`FREE_FAILURES`] wrong
/// guesses from a source, every further check from it is refused for 1 s, then 2 s, 4 s, ...
/// up to 5 minutes, until a right password from it. The [`SOURCES`] most recently seen
/// sources are remembered.
#[derive(Default)]
pub struct Limiter {
    sources: [Option<Source>; SOURCES],
}

/// The outcome of a password check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Check {
    /// Right password.
    Ok,
    /// Wrong password.
    Wrong,
    /// Not checked: too many wrong guesses from this source, try later.
    Locked,
}

impl Limiter {
    /// Checks `password` from source `from` against `hash` at time `now_ms` (the hash is not
    /// computed while the source is locked out).
    pub fn check(&mut self, hash: &PasswordHash, password: &[u8], from: [u8; 4], now_ms: u64) -> Check {
        let index = self.sources.iter().position(|s| s.is_some_and(|s| s.ip == from));
        if let Some(source) = index.and_then(|i| self.sources[i].as_mut()) {
            source.last_ms = now_ms;
            if now_ms < source.locked_until_ms {
                return Check::Locked;
            }
        }
        if hash.matches(password) {
            if let Some(i) = index {
                self.sources[i] = None;
            }
            return Check::Ok;
        }
        let slot = index.unwrap_or_else(|| self.free_or_oldest());
        let source =
            self.sources[slot].get_or_insert(Source { ip: from, failures: 0, locked_until_ms: 0, last_ms: now_ms });
        source.failures = source.failures.saturating_add(1);
        if source.failures >= FREE_FAILURES {
            let exp = (source.failures - FREE_FAILURES).min(20);
            source.locked_until_ms = now_ms + (1000u64 << exp).min(MAX_LOCKOUT_MS);
        }
        Check::Wrong
    }

    /// A free entry, else the one seen least recently (its record is dropped).
    fn free_or_oldest(&mut self) -> usize {
        let slot = match self.sources.iter().position(Option::is_none) {
            Some(free) => free,
            None => (0..SOURCES).min_by_key(|i| self.sources[*i].map_or(0, |s| s.last_ms)).unwrap_or(0),
        };
        self.sources[slot] = None;
        slot
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_and_limit() {
        let h = PasswordHash::factory();
        assert!(h.matches(b"remodaq"));
        assert!(!h.matches(b"remodaq "));
        let salt = h.next_salt(&[2, 0, 0, 0, 0, 1], 5);
        assert_ne!(salt, h.next_salt(&[2, 0, 0, 0, 0, 2], 5));
        let h2 = PasswordHash::new(salt, b"secret");
        assert!(h2.matches(b"secret") && !h2.matches(b"remodaq"));

        let mut l = Limiter::default();
        let a = [10, 0, 0, 1];
        assert_eq!(l.check(&h, b"a", a, 0), Check::Wrong);
        assert_eq!(l.check(&h, b"b", a, 0), Check::Wrong);
        assert_eq!(l.check(&h, b"c", a, 0), Check::Wrong);
        assert_eq!(l.check(&h, b"remodaq", a, 500), Check::Locked, "even the right one, while locked");
        assert_eq!(l.check(&h, b"d", a, 1000), Check::Wrong);
        assert_eq!(l.check(&h, b"remodaq", a, 2999), Check::Locked, "2 s after the fourth");
        assert_eq!(l.check(&h, b"remodaq", a, 3000), Check::Ok);
        assert_eq!(l.check(&h, b"x", a, 3000), Check::Wrong, "reset by the right password");
        assert_eq!(l.check(&h, b"remodaq", a, 3000), Check::Ok);
    }

    #[test]
    fn lock_out_is_per_source() {
        let h = PasswordHash::factory();
        let mut l = Limiter::default();
        let (guesser, admin) = ([10, 0, 0, 66], [10, 0, 0, 1]);
        for _ in 0..10 {
            l.check(&h, b"guess", guesser, 100);
        }
        assert_eq!(l.check(&h, b"remodaq", guesser, 200), Check::Locked);
        assert_eq!(l.check(&h, b"remodaq", admin, 200), Check::Ok, "another source is still accepted");
        assert_eq!(l.check(&h, b"wrong", admin, 200), Check::Wrong, "and gets its own free guesses");
        // 15 other sources guessing after the guesser keep it among the 16 remembered.
        for i in 0..14u8 {
            l.check(&h, b"x", [10, 1, 0, i], 300);
        }
        assert_eq!(l.check(&h, b"remodaq", guesser, 400), Check::Locked, "still remembered");
    }
}
