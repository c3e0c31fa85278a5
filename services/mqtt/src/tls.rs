//! TLS to the broker (docs/mqtt.md, "Decisions"): TLS 1.3 by embedded-tls, the broker's chain
//! checked against the one CA certificate the user installed, its names against the broker's
//! host name, its validity against the module's time ([`Clock`]); without a time, no TLS
//! connection is tried ([`Refused::NoTime`]).

use core::cell::Cell;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embedded_io_async::{Read, Write};
use embedded_tls::{
    Aes128GcmSha256, CertificateEntryRef, CertificateRef, CertificateVerifyRef, CryptoProvider, CryptoRngCore,
    MaxFragmentLength, SignatureScheme, TlsCipherSuite, TlsConfig, TlsConnection, TlsContext, TlsError, TlsVerifier,
};
use sha2::Digest;

pub use crate::records::{Guarded, Whole};

/// TLS's record buffers: [`READ`] for reading, then [`WRITE`] for writing.
pub const BUFFER: usize = READ + WRITE;
/// TLS's read buffer: a record of at most 4 KiB, which the module asks the broker for (the
/// ClientHello's max_fragment_length, RFC 6066: OpenSSL's servers, mosquitto's among them, keep
/// to it), with its overhead (header, tag, content type: 256 B at the most). TLS's own largest
/// record, 16 KiB, would need 12 KiB more of the module's RAM, for a broker's records that are
/// small (its certificates, acknowledgments, commands of at most 512 bytes).
pub const READ: usize = 4_096 + 256;
/// TLS's write buffer (the end of [`BUFFER`]): the module's records are small (a publication of
/// at most about 350 bytes); a larger write goes as more records.
pub const WRITE: usize = 2_048;
/// The longest record the simulator's [`Whole`] holds: a header and [`READ`].
pub const WHOLE: usize = 5 + READ;

/// The module's time for the certificates' validity: seconds since 1970 (SNTP), or `None`
/// before it has one.
pub trait Clock {
    /// Now, or `None`.
    fn now() -> Option<u64>;
}

/// The earliest time the certificates' validity is checked against: 2026-01-01 00:00 UTC
/// (`date -u -d 2026-01-01 +%s`), the year of this firmware. An earlier time is taken as none
/// (no TLS): whoever answers in the time server's place (SNTP has no authentication) cannot set
/// the module's clock back before it to bring a certificate expired earlier back to life.
pub const EARLIEST: u64 = 1_767_225_600;

/// `C`'s time, if it is one to check a certificate against ([`EARLIEST`]).
fn now<C: Clock>() -> Option<u64> {
    C::now().filter(|t| *t >= EARLIEST)
}

/// A board's time of day: ms since 1970, or `None` before it has one.
type TimeOfDay = fn() -> Option<u64>;

/// The board's time of day, for [`BoardClock`]: set by the service before it opens TLS.
static BOARD_TIME: Mutex<CriticalSectionRawMutex, Cell<Option<TimeOfDay>>> = Mutex::new(Cell::new(None));

/// The board's time of day (ms since 1970, or `None`) as the certificates' [`Clock`].
pub struct BoardClock;

impl BoardClock {
    /// Takes the board's time of day from `time_ms`.
    pub fn set(time_ms: TimeOfDay) {
        BOARD_TIME.lock(|t| t.set(Some(time_ms)));
    }
}

impl Clock for BoardClock {
    fn now() -> Option<u64> {
        BOARD_TIME.lock(|t| t.get()).and_then(|f| f()).map(|ms| ms / 1000)
    }
}

/// The TLS randomness: the module's random numbers (`remodaq_shared::password::AUTH`, seeded by
/// the board's entropy: the STM32's RNG; the QEMU board has none, docs/security.md).
pub struct ModuleRng;

impl rand_core::RngCore for ModuleRng {
    fn next_u32(&mut self) -> u32 {
        let mut b = [0u8; 4];
        self.fill_bytes(&mut b);
        u32::from_le_bytes(b)
    }
    fn next_u64(&mut self) -> u64 {
        let mut b = [0u8; 8];
        self.fill_bytes(&mut b);
        u64::from_le_bytes(b)
    }
    fn fill_bytes(&mut self, dest: &mut [u8]) {
        remodaq_shared::password::AUTH.random(b"mqtt tls", dest);
    }
    fn try_fill_bytes(&mut self, dest: &mut [u8]) -> Result<(), rand_core::Error> {
        self.fill_bytes(dest);
        Ok(())
    }
}

impl embedded_tls::CryptoRng for ModuleRng {}

/// What of the broker's identity the handshake showed ([`Checked`]).
const CERTIFICATE: u8 = 1;
const SIGNATURE: u8 = 2;

/// The broker's identity checked (`crate::certificate`), held to the handshake's order, which
/// embedded-tls 0.19 does not enforce: it takes a server's Finished without its Certificate and
/// CertificateVerify (the Finished proves only the key exchange, not who the broker is)
/// (security review of issue #40). Here the broker's certificate is checked once, and only with
/// a time of day; its signature of the handshake only after it; `seen` says which passed, and
/// [`handshake`] refuses a connection unless both did. The broker's certificate signed by the
/// installed CA itself (the CA may follow it): no intermediate.
struct Checked<'a, C> {
    ca: &'a [u8],
    host: &'a str,
    seen: &'a Cell<u8>,
    /// The broker's key and the transcript's hash up to its certificate, once that passed.
    key: Option<(p256::ecdsa::VerifyingKey, [u8; 32])>,
    clock: core::marker::PhantomData<C>,
}

impl<C: Clock> TlsVerifier<Aes128GcmSha256> for Checked<'_, C> {
    fn set_hostname_verification(&mut self, hostname: &str) -> Result<(), TlsError> {
        // The name given to `open`, which the configuration passes on.
        if hostname == self.host {
            Ok(())
        } else {
            Err(TlsError::InvalidCertificate)
        }
    }

    fn verify_certificate(
        &mut self,
        transcript: &<Aes128GcmSha256 as TlsCipherSuite>::Hash,
        cert: CertificateRef,
    ) -> Result<(), TlsError> {
        // The broker's own certificate, and after it at most the installed CA itself (as an
        // OpenSSL server sends it): no intermediate.
        let broker = match cert.entries.as_slice() {
            [CertificateEntryRef::X509(broker)] => broker,
            [CertificateEntryRef::X509(broker), CertificateEntryRef::X509(ca)] if *ca == self.ca => broker,
            _ => return Err(TlsError::InvalidCertificate),
        };
        let now = now::<C>().ok_or(TlsError::InvalidCertificate)?;
        if self.seen.get() != 0 {
            return Err(TlsError::InvalidCertificate);
        }
        let key = crate::certificate::check(self.ca, broker, self.host, now).map_err(|_problem| {
            remodaq_shared::warn!("mqtt: the broker's certificate refused: {}", _problem.what());
            TlsError::InvalidCertificate
        })?;
        self.key = Some((key, transcript.clone().finalize().into()));
        self.seen.set(CERTIFICATE);
        Ok(())
    }

    fn verify_signature(&mut self, verify: CertificateVerifyRef) -> Result<(), TlsError> {
        // The key is there only after the certificate passed, and taken once.
        let (key, transcript) = self.key.take().ok_or(TlsError::InvalidSignature)?;
        if verify.signature_scheme != SignatureScheme::EcdsaSecp256r1Sha256 {
            return Err(TlsError::InvalidSignature);
        }
        crate::certificate::handshake_signed(&key, &transcript, verify.signature)
            .map_err(|_| TlsError::InvalidSignature)?;
        self.seen.set(CERTIFICATE | SIGNATURE);
        Ok(())
    }
}

/// The session's cryptography: randomness from the board, the broker's identity checked.
struct Provider<'a, R, C: Clock> {
    rng: R,
    verifier: Checked<'a, C>,
}

impl<R: CryptoRngCore, C: Clock> CryptoProvider for Provider<'_, R, C> {
    type CipherSuite = Aes128GcmSha256;
    // No client certificate: nothing is signed.
    type Signature = [u8; 0];

    fn rng(&mut self) -> impl CryptoRngCore {
        &mut self.rng
    }

    fn verifier(&mut self) -> Result<&mut impl TlsVerifier<Aes128GcmSha256>, TlsError> {
        Ok(&mut self.verifier)
    }
}

/// Why no TLS connection was made (each counted in the diagnostics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refused {
    /// The module has no time yet: a certificate's validity cannot be checked.
    NoTime,
    /// The broker's chain does not lead to the installed CA, names another host, or is not
    /// valid now.
    Certificate,
    /// The handshake failed otherwise (the link, the broker's alert, a protocol error).
    Handshake,
}

/// A TLS connection to the broker, over `transport` (a TCP connection already open to it).
pub type Tls<'b, T> = TlsConnection<'b, Guarded<T>, Aes128GcmSha256>;

/// Opens TLS on `transport` to the broker named `host`, its chain checked against `ca` (DER),
/// with the record buffers `read` (up to 16 KiB: TLS's largest record) and `write`: a
/// [`connection`] and its [`handshake`].
pub async fn open<'b, T: Read + Write + 'b, R: CryptoRngCore, C: Clock>(
    transport: T,
    read: &'b mut [u8],
    write: &'b mut [u8],
    ca: &[u8],
    host: &str,
    rng: R,
) -> Result<Tls<'b, T>, Refused> {
    let mut tls = connection(transport, read, write);
    handshake::<_, _, C>(&mut tls, ca, host, rng).await?;
    Ok(tls)
}

/// A TLS connection on `transport` with the record buffers `read` and `write`, not open yet
/// ([`handshake`]). Made where it stays (the service's future, `crate::service`): the connection
/// is 1.3 KB, and returned through the handshake's futures by value it was copied through the
/// stack at each (issue #40: its stack).
pub fn connection<'b, T: Read + Write + 'b>(transport: T, read: &'b mut [u8], write: &'b mut [u8]) -> Tls<'b, T> {
    TlsConnection::new(Guarded::new(transport), read, write)
}

/// The handshake of `tls` ([`connection`]) with the broker named `host`, its chain checked
/// against `ca` (DER).
pub async fn handshake<'b, T: Read + Write + 'b, R: CryptoRngCore, C: Clock>(
    tls: &mut Tls<'b, T>,
    ca: &[u8],
    host: &str,
    rng: R,
) -> Result<(), Refused> {
    if now::<C>().is_none() {
        return Err(Refused::NoTime);
    }
    let config = TlsConfig::new().with_server_name(host).with_max_fragment_length(MaxFragmentLength::Bits12);
    let seen = Cell::new(0);
    let verifier = Checked { ca, host, seen: &seen, key: None, clock: core::marker::PhantomData };
    let provider = Provider::<R, C> { rng, verifier };
    match tls.open(TlsContext::new(&config, provider)).await {
        // Nothing of the application's is written before this: a broker that did not show its
        // certificate and prove it holds its key gets no credentials.
        Ok(()) if seen.get() == CERTIFICATE | SIGNATURE => Ok(()),
        Ok(()) => Err(Refused::Certificate),
        Err(TlsError::InvalidCertificate | TlsError::InvalidSignature | TlsError::DecodeError) => {
            Err(Refused::Certificate)
        }
        Err(_) => Err(Refused::Handshake),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Later;

    impl Clock for Later {
        fn now() -> Option<u64> {
            Some(EARLIEST + 1)
        }
    }

    /// `Checked` holds the handshake's order: no signature before a certificate passed, none
    /// after one was refused; nothing marked seen.
    #[test]
    fn no_signature_is_taken_without_a_certificate_that_passed() {
        let seen = Cell::new(0);
        let mut checked =
            Checked::<Later> { ca: &[], host: "broker.test", seen: &seen, key: None, clock: core::marker::PhantomData };
        let verify =
            || CertificateVerifyRef { signature_scheme: SignatureScheme::EcdsaSecp256r1Sha256, signature: &[] };
        assert!(matches!(checked.verify_signature(verify()), Err(TlsError::InvalidSignature)));
        let mut certificate = CertificateRef::with_context(&[]);
        assert!(certificate.entries.push(CertificateEntryRef::X509(&[0x30, 0x00])).is_ok());
        assert!(matches!(
            checked.verify_certificate(&sha2::Sha256::new(), certificate),
            Err(TlsError::InvalidCertificate)
        ));
        assert!(matches!(checked.verify_signature(verify()), Err(TlsError::InvalidSignature)));
        assert_eq!(seen.get(), 0);
    }
}
