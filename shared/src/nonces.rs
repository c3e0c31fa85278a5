//! Nonces a module hands out for a challenge-response and takes back once: the discovery
//! service's (configuration commands) and the web console's (logins).

use remodaq_protocol::auth::NONCE_LEN;

use crate::password::AUTH;

#[derive(Clone, Copy)]
struct Nonce {
    value: [u8; NONCE_LEN],
    issued_ms: u64,
    /// Who asked for it: only a request from there may use it (a forged source never sees the
    /// answer to the real one, so it cannot spend the guessing budget with it).
    to: [u8; 4],
}

/// `N` nonces handed out and not used yet, each valid for `lifetime_ms`.
pub struct Nonces<const N: usize> {
    nonces: [Option<Nonce>; N],
    lifetime_ms: u64,
    one_per_address: bool,
}

impl<const N: usize> Nonces<N> {
    /// None handed out yet; an address may hold several at once (the discovery service: a PC
    /// may configure a module from two programs).
    pub const fn new(lifetime_ms: u64) -> Self {
        Self { nonces: [None; N], lifetime_ms, one_per_address: false }
    }

    /// None handed out yet; a new nonce for an address replaces the one it holds (the web
    /// console: a host asking in a loop pushes out only its own, not another user's).
    pub const fn one_per_address(lifetime_ms: u64) -> Self {
        Self { nonces: [None; N], lifetime_ms, one_per_address: true }
    }

    /// Hands out a fresh random nonce to `from`: its own earlier one is replaced (with
    /// [`one_per_address`](Self::one_per_address)), else the oldest one is forgotten when every
    /// place is taken.
    pub fn issue(&mut self, from: [u8; 4], now_ms: u64) -> [u8; NONCE_LEN] {
        let mut value = [0u8; NONCE_LEN];
        let mut context = [0u8; 12];
        context[..8].copy_from_slice(&now_ms.to_le_bytes());
        context[8..].copy_from_slice(&from);
        AUTH.random(&context, &mut value);
        let own = self.nonces.iter().position(|n| self.one_per_address && n.is_some_and(|n| n.to == from));
        let slot = own.or_else(|| (0..N).min_by_key(|&i| self.nonces[i].map_or(0, |n| n.issued_ms + 1))).unwrap_or(0);
        if let Some(place) = self.nonces.get_mut(slot) {
            *place = Some(Nonce { value, issued_ms: now_ms, to: from });
        }
        value
    }

    /// Takes a nonce handed out to `from` less than the lifetime ago: it can never be used
    /// again (whether or not it was still valid). A nonce handed out to another address stays:
    /// a host that read it on the wire cannot spend it before its owner does.
    pub fn redeem(&mut self, value: &[u8; NONCE_LEN], from: [u8; 4], now_ms: u64) -> bool {
        let lifetime = self.lifetime_ms;
        match self.nonces.iter_mut().find(|n| n.is_some_and(|n| n.value == *value && n.to == from)) {
            Some(slot) => slot.take().is_some_and(|n| now_ms.saturating_sub(n.issued_ms) < lifetime),
            None => false,
        }
    }
}
