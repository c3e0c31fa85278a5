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

/// Rate limit on password checks: after [`FREE_FAILURES`] wrong guesses, every further check
/// is refused for 1 s, then 2 s, 4 s, ... up to 5 minutes, until a right password.
#[derive(Default)]
pub struct Limiter {
    failures: u32,
    locked_until_ms: u64,
}

/// The outcome of a password check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Check {
    /// Right password.
    Ok,
    /// Wrong password.
    Wrong,
    /// Not checked: too many wrong guesses, try later.
    Locked,
}

impl Limiter {
    /// Checks `password` against `hash` at time `now_ms`.
    pub fn check(&mut self, hash: &PasswordHash, password: &[u8], now_ms: u64) -> Check {
        if now_ms < self.locked_until_ms {
            return Check::Locked;
        }
        if hash.matches(password) {
            self.failures = 0;
            return Check::Ok;
        }
        self.failures = self.failures.saturating_add(1);
        if self.failures >= FREE_FAILURES {
            let exp = (self.failures - FREE_FAILURES).min(20);
            self.locked_until_ms = now_ms + (1000u64 << exp).min(MAX_LOCKOUT_MS);
        }
        Check::Wrong
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
        assert_eq!(l.check(&h, b"a", 0), Check::Wrong);
        assert_eq!(l.check(&h, b"b", 0), Check::Wrong);
        assert_eq!(l.check(&h, b"c", 0), Check::Wrong);
        assert_eq!(l.check(&h, b"remodaq", 500), Check::Locked, "even the right one, while locked");
        assert_eq!(l.check(&h, b"d", 1000), Check::Wrong);
        assert_eq!(l.check(&h, b"remodaq", 2999), Check::Locked, "2 s after the fourth");
        assert_eq!(l.check(&h, b"remodaq", 3000), Check::Ok);
        assert_eq!(l.check(&h, b"x", 3000), Check::Wrong, "reset by the right password");
        assert_eq!(l.check(&h, b"remodaq", 3000), Check::Ok);
    }
}
