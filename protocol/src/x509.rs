//! X.509 certificates read in place from their DER bytes, no copy and no decoded structure
//! (docs/mqtt.md, "Decisions"): what MQTT's TLS checks of the broker's certificate
//! (`remodaq_mqtt::certificate`, which adds the P-256 signatures) and what the web console
//! checks of a CA certificate when it is installed. RFC 5280 §4.1 for the certificate, RFC 6125
//! §6.4 for the names.
//!
//! Only what the module's TLS takes is read: version 3, ECDSA P-256 with SHA-256, a P-256 key;
//! anything else (an RSA or P-384 key, an encoding this reader does not take) is refused.

/// ecdsa-with-SHA256 (RFC 5758 §3.2), the OID's content octets.
const ECDSA_SHA256: &[u8] = &[0x2A, 0x86, 0x48, 0xCE, 0x3D, 0x04, 0x03, 0x02];
/// id-ecPublicKey (RFC 5480 §2.1.1).
const EC_PUBLIC_KEY: &[u8] = &[0x2A, 0x86, 0x48, 0xCE, 0x3D, 0x02, 0x01];
/// secp256r1, prime256v1 (RFC 5480 §2.1.1.1).
const P256: &[u8] = &[0x2A, 0x86, 0x48, 0xCE, 0x3D, 0x03, 0x01, 0x07];
/// id-at-commonName (RFC 5280 Appendix A).
const COMMON_NAME: &[u8] = &[0x55, 0x04, 0x03];
/// id-ce-subjectAltName (RFC 5280 §4.2.1.6).
const SUBJECT_ALT_NAME: &[u8] = &[0x55, 0x1D, 0x11];
/// The extensions this check knows, so that one marked critical does not refuse the
/// certificate: subjectKeyIdentifier, keyUsage, subjectAltName, basicConstraints,
/// authorityKeyIdentifier, extKeyUsage (RFC 5280 §4.2.1; id-ce is 2.5.29).
const KNOWN: [u8; 6] = [14, 15, 17, 19, 35, 37];

/// DER's tags used here (X.690 §8).
const BOOLEAN: u8 = 0x01;
const INTEGER: u8 = 0x02;
const BIT_STRING: u8 = 0x03;
const OCTET_STRING: u8 = 0x04;
const OID: u8 = 0x06;
const UTC_TIME: u8 = 0x17;
const GENERALIZED_TIME: u8 = 0x18;
const SEQUENCE: u8 = 0x30;
const SET: u8 = 0x31;
/// `[0]` EXPLICIT, constructed: the certificate's version.
const VERSION: u8 = 0xA0;
/// `[3]` EXPLICIT, constructed: the certificate's extensions.
const EXTENSIONS: u8 = 0xA3;
/// GeneralName's dNSName, `[2]` IMPLICIT IA5String.
const DNS_NAME: u8 = 0x82;
/// GeneralName's uniformResourceIdentifier, `[6]` IMPLICIT IA5String.
const URI: u8 = 0x86;
/// GeneralName's otherName, `[0]` IMPLICIT, constructed (an SRV name among others).
const OTHER_NAME: u8 = 0xA0;
/// id-kp-serverAuth (RFC 5280 §4.2.1.12).
const SERVER_AUTH: &[u8] = &[0x2B, 0x06, 0x01, 0x05, 0x05, 0x07, 0x03, 0x01];
/// anyExtendedKeyUsage (RFC 5280 §4.2.1.12).
const ANY_PURPOSE: &[u8] = &[0x55, 0x1D, 0x25, 0x00];

/// Why a certificate was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Problem {
    /// Not DER this reader takes, or not a certificate.
    Encoding,
    /// Not ECDSA P-256 with SHA-256, or not a P-256 key.
    Algorithm,
    /// The broker's certificate is not the CA's: another issuer, or a signature that fails.
    Signature,
    /// The module's time is outside the certificate's validity.
    Time,
    /// A critical extension this check does not know, or one twice.
    Critical,
    /// A certificate not for a TLS server: a CA's, or its key's usage another.
    Purpose,
    /// The host name is not one of the certificate's names.
    Name,
}

impl Problem {
    /// What went wrong, for the log.
    pub fn what(self) -> &'static str {
        match self {
            Problem::Encoding => "not a certificate this module reads",
            Problem::Algorithm => "not ECDSA P-256 with SHA-256",
            Problem::Signature => "not signed by the CA installed",
            Problem::Time => "not valid at the module's time",
            Problem::Critical => "a critical extension unknown to the module",
            Problem::Purpose => "not a TLS server's certificate",
            Problem::Name => "not the broker's host name",
        }
    }
}

/// A DER reader over a slice: each element read as its tag, its content and its whole encoding.
#[derive(Clone, Copy)]
struct Der<'a>(&'a [u8]);

impl<'a> Der<'a> {
    /// The next element: (tag, content, the element's whole bytes). Only single-byte tags and
    /// definite lengths of at most two bytes, minimally encoded (a certificate is below 64 KiB).
    fn next(&mut self) -> Result<(u8, &'a [u8], &'a [u8]), Problem> {
        let all = self.0;
        let (&tag, rest) = all.split_first().ok_or(Problem::Encoding)?;
        if tag & 0x1F == 0x1F {
            return Err(Problem::Encoding);
        }
        let (&first, rest) = rest.split_first().ok_or(Problem::Encoding)?;
        let (len, rest) = match first {
            0..=0x7F => (usize::from(first), rest),
            0x81 => match rest {
                [n @ 0x80..=0xFF, rest @ ..] => (usize::from(*n), rest),
                _ => return Err(Problem::Encoding),
            },
            0x82 => match rest {
                [hi @ 1..=0xFF, lo, rest @ ..] => (usize::from(*hi) << 8 | usize::from(*lo), rest),
                _ => return Err(Problem::Encoding),
            },
            _ => return Err(Problem::Encoding),
        };
        if rest.len() < len {
            return Err(Problem::Encoding);
        }
        let (content, after) = rest.split_at(len);
        self.0 = after;
        Ok((tag, content, &all[..all.len() - after.len()]))
    }

    /// The next element's content, which must have `tag`.
    fn take(&mut self, tag: u8) -> Result<&'a [u8], Problem> {
        match self.next()? {
            (t, content, _) if t == tag => Ok(content),
            _ => Err(Problem::Encoding),
        }
    }

    /// The next element's content if it has `tag`; nothing read otherwise.
    fn optional(&mut self, tag: u8) -> Result<Option<&'a [u8]>, Problem> {
        match self.0.first() {
            Some(&t) if t == tag => self.take(tag).map(Some),
            _ => Ok(None),
        }
    }

    fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// What the checks read of a certificate (every field a slice of its DER bytes).
#[derive(Clone, Copy)]
pub struct Certificate<'a> {
    /// The signed part, tbsCertificate, whole.
    signed: &'a [u8],
    /// The issuer's Name, whole.
    issuer: &'a [u8],
    /// The subject's Name, whole.
    subject: &'a [u8],
    /// notBefore and notAfter, seconds since 1970 (0 for any time before).
    valid: (u64, u64),
    /// The subject's public key: a P-256 point, SEC1-encoded.
    key: &'a [u8],
    /// The extensions' SEQUENCE content (empty without).
    extensions: &'a [u8],
    /// The signature, ECDSA-Sig-Value's DER.
    signature: &'a [u8],
}

impl<'a> Certificate<'a> {
    /// Reads `der`, a certificate signed with ECDSA P-256 SHA-256 whose key is a P-256 key.
    pub fn read(der: &'a [u8]) -> Result<Self, Problem> {
        let mut outer = Der(der);
        let mut certificate = Der(outer.take(SEQUENCE)?);
        if !outer.is_empty() {
            return Err(Problem::Encoding);
        }
        let (tag, tbs, signed) = certificate.next()?;
        if tag != SEQUENCE {
            return Err(Problem::Encoding);
        }
        let algorithm = certificate.take(SEQUENCE)?;
        let signature = match certificate.take(BIT_STRING)? {
            [0, signature @ ..] => signature,
            _ => return Err(Problem::Encoding),
        };
        if !certificate.is_empty() {
            return Err(Problem::Encoding);
        }
        ecdsa_sha256(algorithm)?;

        let mut tbs = Der(tbs);
        // v3 (2) only: extensions and names as this check reads them.
        if tbs.take(VERSION)? != [INTEGER, 1, 2] {
            return Err(Problem::Encoding);
        }
        tbs.take(INTEGER)?;
        if tbs.take(SEQUENCE)? != algorithm {
            return Err(Problem::Algorithm);
        }
        let (_, _, issuer) = tbs.next()?;
        let mut validity = Der(tbs.take(SEQUENCE)?);
        let valid = (time(validity.next()?)?, time(validity.next()?)?);
        if !validity.is_empty() {
            return Err(Problem::Encoding);
        }
        let (_, _, subject) = tbs.next()?;
        if issuer.first() != Some(&SEQUENCE) || subject.first() != Some(&SEQUENCE) {
            return Err(Problem::Encoding);
        }
        let mut info = Der(tbs.take(SEQUENCE)?);
        let mut key_algorithm = Der(info.take(SEQUENCE)?);
        if key_algorithm.take(OID)? != EC_PUBLIC_KEY || key_algorithm.take(OID)? != P256 || !key_algorithm.is_empty() {
            return Err(Problem::Algorithm);
        }
        let key = match info.take(BIT_STRING)? {
            [0, key @ ..] if info.is_empty() => key,
            _ => return Err(Problem::Encoding),
        };
        // Neither unique identifier (RFC 5280 §4.1.2.8: CAs should not make them) is taken.
        let extensions = match tbs.optional(EXTENSIONS)? {
            Some(explicit) => {
                let mut explicit = Der(explicit);
                let list = explicit.take(SEQUENCE)?;
                if !explicit.is_empty() {
                    return Err(Problem::Encoding);
                }
                list
            }
            None => &[],
        };
        if !tbs.is_empty() {
            return Err(Problem::Encoding);
        }
        Ok(Certificate { signed, issuer, subject, valid, key, extensions, signature })
    }

    /// The signed part, tbsCertificate, whole (what the issuer's signature covers).
    pub fn signed(&self) -> &'a [u8] {
        self.signed
    }

    /// The issuer's Name, whole.
    pub fn issuer(&self) -> &'a [u8] {
        self.issuer
    }

    /// The subject's Name, whole.
    pub fn subject(&self) -> &'a [u8] {
        self.subject
    }

    /// The subject's public key: a P-256 point, SEC1-encoded (not yet checked to be on the
    /// curve: the signature checks' part).
    pub fn key_point(&self) -> &'a [u8] {
        self.key
    }

    /// The issuer's signature, an ECDSA-Sig-Value's DER ([`ecdsa_signature`]).
    pub fn signature(&self) -> &'a [u8] {
        self.signature
    }

    /// Whether `now` (seconds since 1970) is within the validity.
    pub fn valid_at(&self, now: u64) -> Result<(), Problem> {
        if (self.valid.0..=self.valid.1).contains(&now) {
            Ok(())
        } else {
            Err(Problem::Time)
        }
    }

    /// The extensions: each one's id (its OID's content), whether critical, and its value.
    fn each_extension(
        &self,
        mut f: impl FnMut(&'a [u8], bool, &'a [u8]) -> Result<(), Problem>,
    ) -> Result<(), Problem> {
        let mut list = Der(self.extensions);
        while !list.is_empty() {
            let mut extension = Der(list.take(SEQUENCE)?);
            let id = extension.take(OID)?;
            // DER leaves FALSE out (X.690 §11.5); some CAs write it all the same.
            let critical = match extension.optional(BOOLEAN)? {
                None | Some([0x00]) => false,
                Some([0xFF]) => true,
                Some(_) => return Err(Problem::Encoding),
            };
            let value = extension.take(OCTET_STRING)?;
            if !extension.is_empty() {
                return Err(Problem::Encoding);
            }
            f(id, critical, value)?;
        }
        Ok(())
    }

    /// No extension is critical that this check does not know, and none comes twice (RFC 5280
    /// §4.2).
    pub fn no_unknown_critical(&self) -> Result<(), Problem> {
        self.each_extension(|id, critical, _| {
            let mut seen = 0;
            self.each_extension(|other, _, _| {
                seen += usize::from(other == id);
                Ok(())
            })?;
            match id {
                _ if seen > 1 => Err(Problem::Encoding),
                [0x55, 0x1D, n] if KNOWN.contains(n) => Ok(()),
                _ if critical => Err(Problem::Critical),
                _ => Ok(()),
            }
        })
    }

    /// Whether the certificate may be a TLS server's (RFC 5280 §4.2.1.3, §4.2.1.9, §4.2.1.12;
    /// RFC 8446 §4.4.2.2): not a CA's (unless `is_the_ca`: the very certificate the user
    /// installed, a self-signed broker's); a key usage, if it says, for digital signatures; an
    /// extended key usage, if it says, for a TLS server (or any).
    pub fn serves_tls(&self, is_the_ca: bool) -> Result<(), Problem> {
        self.each_extension(|id, _, value| {
            let mut value = Der(value);
            match id {
                [0x55, 0x1D, 19] => {
                    let mut constraints = Der(value.take(SEQUENCE)?);
                    if constraints.optional(BOOLEAN)? == Some(&[0xFF]) && !is_the_ca {
                        return Err(Problem::Purpose);
                    }
                }
                [0x55, 0x1D, 15] => match value.take(BIT_STRING)? {
                    [_, first, ..] if first & 0x80 != 0 => {}
                    _ => return Err(Problem::Purpose),
                },
                [0x55, 0x1D, 37] => {
                    let mut purposes = Der(value.take(SEQUENCE)?);
                    let mut server = false;
                    while !purposes.is_empty() {
                        server |= matches!(purposes.take(OID)?, SERVER_AUTH | ANY_PURPOSE);
                    }
                    if !server {
                        return Err(Problem::Purpose);
                    }
                }
                _ => return Ok(()),
            }
            if value.is_empty() {
                Ok(())
            } else {
                Err(Problem::Encoding)
            }
        })
    }

    /// Whether `host` is one of this certificate's DNS names (RFC 6125 §6.4.4: its subject's
    /// common name counts only when it has no DNS, URI or other name, its addresses aside). An
    /// address is no host name here: the broker's TLS name is a name (docs/mqtt.md).
    pub fn names(&self, host: &str) -> Result<(), Problem> {
        if host.parse::<core::net::Ipv4Addr>().is_ok() {
            return Err(Problem::Name);
        }
        let mut identifiers = 0usize;
        let mut matched = false;
        self.each_extension(|id, _, value| {
            if id == SUBJECT_ALT_NAME {
                let mut outer = Der(value);
                let mut names = Der(outer.take(SEQUENCE)?);
                if !outer.is_empty() {
                    return Err(Problem::Encoding);
                }
                while !names.is_empty() {
                    match names.next()? {
                        (DNS_NAME, name, _) => {
                            identifiers += 1;
                            matched |= name_matches(name, host.as_bytes());
                        }
                        (URI | OTHER_NAME, _, _) => identifiers += 1,
                        _ => {}
                    }
                }
            }
            Ok(())
        })?;
        if identifiers == 0 {
            matched = self.common_name()?.is_some_and(|name| name_matches(name, host.as_bytes()));
        }
        if matched {
            Ok(())
        } else {
            Err(Problem::Name)
        }
    }

    /// The subject's last common name, if it has one.
    fn common_name(&self) -> Result<Option<&'a [u8]>, Problem> {
        let mut name = Der(self.subject);
        let mut rdns = Der(name.take(SEQUENCE)?);
        let mut found = None;
        while !rdns.is_empty() {
            let mut set = Der(rdns.take(SET)?);
            while !set.is_empty() {
                let mut attribute = Der(set.take(SEQUENCE)?);
                if attribute.take(OID)? == COMMON_NAME {
                    found = Some(attribute.next()?.1);
                    if !attribute.is_empty() {
                        return Err(Problem::Encoding);
                    }
                }
            }
        }
        Ok(found)
    }
}

/// An AlgorithmIdentifier's content that must be ecdsa-with-SHA256 with no parameters.
fn ecdsa_sha256(algorithm: &[u8]) -> Result<(), Problem> {
    let mut algorithm = Der(algorithm);
    if algorithm.take(OID)? == ECDSA_SHA256 && algorithm.is_empty() {
        Ok(())
    } else {
        Err(Problem::Algorithm)
    }
}

/// An ECDSA-Sig-Value's DER (RFC 5480 §2.2.3: `SEQUENCE { r INTEGER, s INTEGER }`) as a P-256
/// signature's r and s, 32 bytes each, big-endian.
pub fn ecdsa_signature(der: &[u8]) -> Option<[u8; 64]> {
    let mut outer = Der(der);
    let mut value = Der(outer.take(SEQUENCE).ok()?);
    let mut bytes = [0u8; 64];
    for half in bytes.chunks_exact_mut(32) {
        let integer = value.take(INTEGER).ok()?;
        // Positive and minimal: a leading zero only before a byte with its top bit set.
        let magnitude = match integer {
            [0, rest @ ..] if rest.first().is_some_and(|b| b & 0x80 != 0) => rest,
            [first, ..] if first & 0x80 == 0 && *first != 0 => integer,
            _ => return None,
        };
        let start = half.len().checked_sub(magnitude.len())?;
        half[start..].copy_from_slice(magnitude);
    }
    if !value.is_empty() || !outer.is_empty() {
        return None;
    }
    Some(bytes)
}

/// A validity time (RFC 5280 §4.1.2.5: UTCTime `YYMMDDHHMMSSZ` through 2049, GeneralizedTime
/// `YYYYMMDDHHMMSSZ` after) as seconds since 1970 (0 for any time before).
fn time((tag, text, _): (u8, &[u8], &[u8])) -> Result<u64, Problem> {
    let (year, rest) = match (tag, text.len()) {
        (UTC_TIME, 13) => {
            let yy = two(&text[..2])?;
            (if yy >= 50 { 1900 + yy } else { 2000 + yy }, &text[2..])
        }
        (GENERALIZED_TIME, 15) => (two(&text[..2])? * 100 + two(&text[2..4])?, &text[4..]),
        _ => return Err(Problem::Encoding),
    };
    let [m0, m1, d0, d1, h0, h1, i0, i1, s0, s1, b'Z'] = *rest else {
        return Err(Problem::Encoding);
    };
    let (month, day) = (two(&[m0, m1])?, two(&[d0, d1])?);
    let (hour, minute, second) = (two(&[h0, h1])?, two(&[i0, i1])?, two(&[s0, s1])?);
    let leap = year % 4 == 0 && (year % 100 != 0 || year % 400 == 0);
    let days = match month {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    };
    if !(1..=12).contains(&month) || !(1..=days).contains(&day) || hour > 23 || minute > 59 || second > 59 {
        return Err(Problem::Encoding);
    }
    let seconds = days_from_1970(year, month, day) * 86_400 + i64::from(hour * 3600 + minute * 60 + second);
    Ok(u64::try_from(seconds).unwrap_or(0))
}

/// Two decimal digits.
fn two(digits: &[u8]) -> Result<u32, Problem> {
    match digits {
        [a @ b'0'..=b'9', b @ b'0'..=b'9'] => Ok(u32::from(a - b'0') * 10 + u32::from(b - b'0')),
        _ => Err(Problem::Encoding),
    }
}

/// Days from 1970-01-01 to a date of the proleptic Gregorian calendar (the civil-from-days
/// inverse of H. Hinnant's "chrono-Compatible Low-Level Date Algorithms").
fn days_from_1970(year: u32, month: u32, day: u32) -> i64 {
    let year = i64::from(year) - i64::from(month <= 2);
    let era = year.div_euclid(400);
    let year_of_era = year - era * 400;
    let month = i64::from(month);
    let day_of_year = (153 * (if month > 2 { month - 3 } else { month + 9 }) + 2) / 5 + i64::from(day) - 1;
    let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
    era * 146_097 + day_of_era - 719_468
}

/// RFC 6125 §6.4.3: ASCII case ignored; a `*` only as the whole left-most label, standing for
/// exactly one label of the host, and only above two labels of the name (not `*.test`).
fn name_matches(name: &[u8], host: &[u8]) -> bool {
    match name.strip_prefix(b"*.") {
        Some(rest) => {
            let Some(dot) = host.iter().position(|&b| b == b'.') else { return false };
            dot > 0 && rest.contains(&b'.') && host[dot + 1..].eq_ignore_ascii_case(rest)
        }
        None => !name.is_empty() && name.eq_ignore_ascii_case(host),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Expected values from `date -u -d @N` (GNU coreutils), not from this code.
    #[test]
    fn validity_times_are_read_as_utc_seconds() {
        let utc = |s: &str| time((UTC_TIME, s.as_bytes(), &[]));
        let generalized = |s: &str| time((GENERALIZED_TIME, s.as_bytes(), &[]));
        // date -u -d @1796515200: Sun Dec  6 00:00:00 UTC 2026
        assert_eq!(utc("261206000000Z"), Ok(1_796_515_200));
        // date -u -d @2524607999: Fri Dec 31 23:59:59 UTC 2049
        assert_eq!(utc("491231235959Z"), Ok(2_524_607_999));
        // date -u -d @951782400: Tue Feb 29 00:00:00 UTC 2000
        assert_eq!(utc("000229000000Z"), Ok(951_782_400));
        // date -u -d @2556144000: Sun Jan  1 00:00:00 UTC 2051
        assert_eq!(generalized("20510101000000Z"), Ok(2_556_144_000));
        // 1950 to 1969: before 1970, 0.
        assert_eq!(utc("500101000000Z"), Ok(0));
        // No 31 February, 29 February only in a leap year (2100 is none, 2000 was).
        assert_eq!(generalized("21000229000000Z"), Err(Problem::Encoding));
        for bad in [
            "261206000000",
            "2612060000000",
            "261306000000Z",
            "261206240000Z",
            "26120600000+Z",
            "270231000000Z",
            "270229000000Z",
            "260431000000Z",
        ] {
            assert_eq!(utc(bad), Err(Problem::Encoding), "{bad}");
        }
    }

    #[test]
    fn a_wildcard_stands_for_one_left_most_label() {
        assert!(name_matches(b"broker.test", b"Broker.TEST"));
        assert!(name_matches(b"*.plant.test", b"broker.plant.test"));
        assert!(!name_matches(b"*.plant.test", b"a.broker.plant.test"));
        assert!(!name_matches(b"*.plant.test", b"plant.test"));
        assert!(!name_matches(b"*.plant.test", b".plant.test"));
        assert!(!name_matches(b"*.test", b"broker.test"));
        assert!(!name_matches(b"b*.plant.test", b"broker.plant.test"));
        assert!(!name_matches(b"", b""));
    }

    #[test]
    fn the_reader_refuses_what_it_does_not_take() {
        // A length past the end, a long form where the short one fits, a multi-byte tag.
        for junk in [&[0x30, 0x05, 0x02][..], &[0x30, 0x81, 0x05, 0, 0, 0, 0, 0], &[0x1F, 0x01, 0x00], &[]] {
            assert!(Der(junk).next().is_err(), "{junk:?}");
        }
        assert!(Certificate::read(&[0x30, 0x00]).is_err());
        // ECDSA-Sig-Value: a negative r, a non-minimal one, 33 bytes of magnitude.
        assert!(ecdsa_signature(&[0x30, 0x06, 0x02, 0x01, 0x80, 0x02, 0x01, 0x01]).is_none());
        assert!(ecdsa_signature(&[0x30, 0x07, 0x02, 0x02, 0x00, 0x01, 0x02, 0x01, 0x01]).is_none());
        let mut long = [0u8; 41];
        long[..5].copy_from_slice(&[0x30, 39, 0x02, 34, 0x00]);
        long[5..38].fill(0x80);
        long[38..].copy_from_slice(&[0x02, 0x01, 0x01]);
        assert!(ecdsa_signature(&long).is_none());
    }
}
