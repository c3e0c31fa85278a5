//! The broker's certificate checked against the CA certificate the user installed (docs/mqtt.md,
//! "Decisions"): X.509 read in place from its DER bytes, no copy and no decoded structure
//! (`remodaq_protocol::x509`, which the web console also checks a CA with when it is
//! installed), and the P-256 signatures here.
//! embedded-tls's `rustpki` verifier, which decoded both certificates into structures of every
//! field, took 22 KB of the handshake's stack (30 KB in all; 12.8 KB with this check) and 27 KB
//! of flash for the `der` crate's decoders (docs/mqtt.md, "Sizes").
//!
//! What is checked (RFC 5280 §4.1 and §6.1 for a path of one certificate under the trust anchor;
//! RFC 6125 §6.4 for the name; RFC 8446 §4.4.3 for the handshake's signature):
//! - the broker's certificate is signed by the installed CA's key with ECDSA P-256 SHA-256, and
//!   its issuer is the CA's subject, byte for byte;
//! - the module's time is within its validity;
//! - no extension it marks critical is one this check does not know, none comes twice;
//! - it is a TLS server's: not a CA's (but for the very certificate installed as the CA, a
//!   self-signed broker's), its key usage and extended key usage, where given, a server's;
//! - the host name the user gave for the broker is one of its DNS names (its subject's common
//!   name only when it has none), a wildcard standing for one whole left-most label;
//! - its key is a P-256 key, which signed the handshake's transcript (the server's
//!   CertificateVerify, `ecdsa_secp256r1_sha256`).
//!
//! Anything else (an RSA or P-384 key, an encoding this reader does not take) is refused: the
//! module's TLS is P-256 only, as the CA it documents.

use p256::ecdsa::signature::Verifier;
use p256::ecdsa::{Signature, VerifyingKey};
pub use remodaq_protocol::x509::{Certificate, Problem};

/// A certificate's P-256 parts: its key, and whether another's key signed it.
pub trait Keys {
    /// The subject's P-256 key.
    fn key(&self) -> Result<VerifyingKey, Problem>;
    /// Whether `issuer` (the CA) signed this certificate: its name is this one's issuer, and
    /// its key's signature of the signed part holds.
    fn signed_by(&self, issuer: &Certificate) -> Result<(), Problem>;
}

impl Keys for Certificate<'_> {
    fn key(&self) -> Result<VerifyingKey, Problem> {
        VerifyingKey::from_sec1_bytes(self.key_point()).map_err(|_| Problem::Algorithm)
    }

    fn signed_by(&self, issuer: &Certificate) -> Result<(), Problem> {
        if self.issuer() != issuer.subject() {
            return Err(Problem::Signature);
        }
        let signature = signature(self.signature()).ok_or(Problem::Signature)?;
        issuer.key()?.verify(self.signed(), &signature).map_err(|_| Problem::Signature)
    }
}

/// An ECDSA-Sig-Value's DER as a P-256 signature (`remodaq_protocol::x509::ecdsa_signature`).
pub fn signature(der: &[u8]) -> Option<Signature> {
    Signature::from_slice(&remodaq_protocol::x509::ecdsa_signature(der)?).ok()
}

/// The broker's certificate checked against `ca` for `host` at `now` (seconds since 1970):
/// the broker's key, once it passed.
pub fn check(ca_der: &[u8], broker_der: &[u8], host: &str, now: u64) -> Result<VerifyingKey, Problem> {
    let ca = Certificate::read(ca_der)?;
    let broker = Certificate::read(broker_der)?;
    broker.signed_by(&ca)?;
    broker.valid_at(now)?;
    broker.no_unknown_critical()?;
    broker.serves_tls(broker_der == ca_der)?;
    broker.names(host)?;
    broker.key()
}

/// TLS 1.3's CertificateVerify (RFC 8446 §4.4.3): `signature` (DER, ecdsa_secp256r1_sha256) of
/// 64 spaces, the server's context string, a zero byte and the transcript's hash `transcript`,
/// by `key`.
pub fn handshake_signed(key: &VerifyingKey, transcript: &[u8; 32], signature: &[u8]) -> Result<(), Problem> {
    const CONTEXT: &[u8] = b"TLS 1.3, server CertificateVerify\x00";
    let mut message = [0x20u8; 64 + CONTEXT.len() + 32];
    message[64..64 + CONTEXT.len()].copy_from_slice(CONTEXT);
    message[64 + CONTEXT.len()..].copy_from_slice(transcript);
    let signature = self::signature(signature).ok_or(Problem::Signature)?;
    key.verify(&message, &signature).map_err(|_| Problem::Signature)
}
