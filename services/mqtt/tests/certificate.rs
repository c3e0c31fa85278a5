//! The broker's certificate check (`remodaq_mqtt::certificate`) on certificates `openssl` makes
//! here: what OpenSSL signed and named is what is expected, each refusal for its own reason.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{SystemTime, UNIX_EPOCH};

use remodaq_mqtt::certificate::{check, handshake_signed, Certificate, Keys, Problem};

const DAY: u64 = 86_400;

fn openssl(dir: &Path, args: &[&str]) {
    let out = Command::new("openssl").current_dir(dir).args(args).output().expect("openssl");
    assert!(out.status.success(), "openssl {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// A directory of its own for one test's files.
fn dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rdaq-certificate-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("a directory");
    dir
}

/// A key `name.key`: P-256, or RSA.
fn key(dir: &Path, name: &str, rsa: bool) -> String {
    let key = format!("{name}.key");
    if rsa {
        openssl(dir, &["genrsa", "-out", &key, "2048"]);
    } else {
        openssl(dir, &["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", &key]);
    }
    key
}

/// A self-signed certificate `name` (openssl's `req -x509`: CA:TRUE) for `subject`, valid two
/// days, with `more` of openssl's arguments; its DER.
fn self_signed(dir: &Path, name: &str, subject: &str, rsa: bool, more: &[&str]) -> Vec<u8> {
    let key = key(dir, name, rsa);
    let pem = format!("{name}.pem");
    let mut args = vec!["req", "-x509", "-new", "-key", &key, "-subj", subject, "-days", "2", "-out", &pem];
    args.extend_from_slice(more);
    openssl(dir, &args);
    der(dir, &pem)
}

/// A CA `name` (P-256 unless `rsa`), self-signed as `rdaq NAME`; its DER.
fn ca(dir: &Path, name: &str, rsa: bool) -> Vec<u8> {
    self_signed(dir, name, &format!("/CN=rdaq {name}"), rsa, &[])
}

/// A certificate `name` for `subject`, with the extensions `ext` (openssl's extfile lines),
/// signed by the CA `by`, valid one day; its DER.
fn issue(dir: &Path, name: &str, subject: &str, ext: &str, by: &str, rsa: bool) -> Vec<u8> {
    let key = key(dir, name, rsa);
    let csr = format!("{name}.csr");
    openssl(dir, &["req", "-new", "-key", &key, "-subj", subject, "-out", &csr]);
    let extfile = format!("{name}.ext");
    let ext =
        if ext.contains("basicConstraints") { ext.to_string() } else { format!("basicConstraints=CA:FALSE\n{ext}") };
    std::fs::write(dir.join(&extfile), ext).expect("ext");
    let pem = format!("{name}.pem");
    let (ca, ca_key) = (format!("{by}.pem"), format!("{by}.key"));
    openssl(
        dir,
        &[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            &ca,
            "-CAkey",
            &ca_key,
            "-CAcreateserial",
            "-days",
            "1",
            "-extfile",
            &extfile,
            "-out",
            &pem,
        ],
    );
    der(dir, &pem)
}

fn der(dir: &Path, pem: &str) -> Vec<u8> {
    let out = format!("{pem}.der");
    openssl(dir, &["x509", "-in", pem, "-outform", "DER", "-out", &out]);
    std::fs::read(dir.join(out)).expect("DER")
}

/// A minute from now: openssl may stamp a certificate's notBefore a second after a test began.
fn soon() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).expect("after 1970").as_secs() + 60
}

#[test]
fn a_broker_certificate_is_taken_only_from_the_ca_for_its_name_and_time() {
    let d = dir("chain");
    let ca_der = ca(&d, "ca", false);
    let other = ca(&d, "other", false);
    let broker = issue(&d, "broker", "/CN=broker.test", "subjectAltName=DNS:broker.test\n", "ca", false);
    let now = soon();
    assert!(check(&ca_der, &broker, "broker.test", now).is_ok());
    assert!(check(&ca_der, &broker, "BROKER.Test", now).is_ok(), "ASCII case ignored");
    assert_eq!(check(&ca_der, &broker, "other.test", now).err(), Some(Problem::Name));
    assert_eq!(check(&ca_der, &broker, "broker.test", now + 2 * DAY).err(), Some(Problem::Time), "expired");
    assert_eq!(check(&ca_der, &broker, "broker.test", now - 3600).err(), Some(Problem::Time), "not yet valid");
    assert_eq!(check(&other, &broker, "broker.test", now).err(), Some(Problem::Signature), "another CA");

    // Signed by another CA that took the first one's name: its signature fails.
    let d2 = dir("impostor");
    let impostor_ca = ca(&d2, "ca", false);
    assert_ne!(impostor_ca, ca_der);
    let forged = issue(&d2, "broker", "/CN=broker.test", "subjectAltName=DNS:broker.test\n", "ca", false);
    assert_eq!(check(&ca_der, &forged, "broker.test", now).err(), Some(Problem::Signature), "same issuer name");
    assert!(check(&impostor_ca, &forged, "broker.test", now).is_ok());

    // One byte changed in the signed part (the subject's name), or in the signature.
    let mut changed = broker.clone();
    let at = changed.windows(11).position(|w| w == b"broker.test").expect("the name");
    changed[at] = b'c';
    assert_eq!(check(&ca_der, &changed, "croker.test", now).err(), Some(Problem::Signature));
    let mut changed = broker.clone();
    let last = changed.len() - 1;
    changed[last] ^= 1;
    assert_eq!(check(&ca_der, &changed, "broker.test", now).err(), Some(Problem::Signature));

    // Cut anywhere: refused, never a panic.
    for len in 0..broker.len() {
        assert!(check(&ca_der, &broker[..len], "broker.test", now).is_err(), "cut at {len}");
    }
    let _ = std::fs::remove_dir_all(d);
    let _ = std::fs::remove_dir_all(d2);
}

#[test]
fn names_follow_rfc_6125() {
    let d = dir("names");
    let ca_der = ca(&d, "ca", false);
    let now = soon();
    // The common name counts only without DNS names.
    let cn_only = issue(&d, "cn", "/CN=broker.test", "", "ca", false);
    assert!(check(&ca_der, &cn_only, "broker.test", now).is_ok());
    let both = issue(&d, "both", "/CN=broker.test", "subjectAltName=DNS:mqtt.test\n", "ca", false);
    assert_eq!(check(&ca_der, &both, "broker.test", now).err(), Some(Problem::Name));
    assert!(check(&ca_der, &both, "mqtt.test", now).is_ok());
    // A URI is an identifier too: the common name no longer counts beside it.
    let uri = issue(&d, "uri", "/CN=broker.test", "subjectAltName=URI:mqtts://mqtt.test\n", "ca", false);
    assert_eq!(check(&ca_der, &uri, "broker.test", now).err(), Some(Problem::Name));
    // An address is no DNS name; the DNS names beside it still count.
    let ip = issue(&d, "ip", "/CN=broker.test", "subjectAltName=IP:192.0.2.5,DNS:mqtt.test\n", "ca", false);
    assert_eq!(check(&ca_der, &ip, "192.0.2.5", now).err(), Some(Problem::Name));
    assert!(check(&ca_der, &ip, "mqtt.test", now).is_ok());
    // A wildcard: one whole left-most label.
    let wild = issue(&d, "wild", "/CN=plant", "subjectAltName=DNS:*.plant.test\n", "ca", false);
    assert!(check(&ca_der, &wild, "mqtt.plant.test", now).is_ok());
    for host in ["plant.test", "a.mqtt.plant.test", "mqtt.plant.test.evil"] {
        assert_eq!(check(&ca_der, &wild, host, now).err(), Some(Problem::Name), "{host}");
    }
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn only_p256_and_known_critical_extensions_are_taken() {
    let d = dir("algorithms");
    let ca_der = ca(&d, "ca", false);
    let rsa_ca = ca(&d, "rsaca", true);
    let now = soon();
    let san = "subjectAltName=DNS:broker.test\n";
    let rsa_key = issue(&d, "rsakey", "/CN=broker.test", san, "ca", true);
    assert_eq!(check(&ca_der, &rsa_key, "broker.test", now).err(), Some(Problem::Algorithm), "an RSA key");
    let by_rsa = issue(&d, "byrsa", "/CN=broker.test", san, "rsaca", false);
    assert_eq!(check(&rsa_ca, &by_rsa, "broker.test", now).err(), Some(Problem::Algorithm), "signed with RSA");
    // Critical: one this check does not know (refused), one it knows (keyUsage: taken).
    let unknown =
        issue(&d, "unknown", "/CN=broker.test", &format!("{san}1.3.6.1.4.1.99999.1=critical,ASN1:NULL\n"), "ca", false);
    assert_eq!(check(&ca_der, &unknown, "broker.test", now).err(), Some(Problem::Critical));
    let known =
        issue(&d, "known", "/CN=broker.test", &format!("{san}keyUsage=critical,digitalSignature\n"), "ca", false);
    assert!(check(&ca_der, &known, "broker.test", now).is_ok());
    let _ = std::fs::remove_dir_all(d);
}

/// The handshake's CertificateVerify as OpenSSL signs it (RFC 8446 §4.4.3's message, signed by
/// `openssl dgst -sha256 -sign`), checked with the key of the broker's certificate.
#[test]
fn the_handshake_signature_is_the_certificate_keys() {
    let d = dir("verify");
    let ca_der = ca(&d, "ca", false);
    let broker = issue(&d, "broker", "/CN=broker.test", "subjectAltName=DNS:broker.test\n", "ca", false);
    let transcript: [u8; 32] = core::array::from_fn(|i| i as u8 * 7);
    let mut message = vec![0x20u8; 64];
    message.extend_from_slice(b"TLS 1.3, server CertificateVerify\x00");
    message.extend_from_slice(&transcript);
    std::fs::write(d.join("message"), &message).expect("message");
    openssl(&d, &["dgst", "-sha256", "-sign", "broker.key", "-out", "signature", "message"]);
    let signature = std::fs::read(d.join("signature")).expect("signature");
    let key = check(&ca_der, &broker, "broker.test", soon()).expect("the broker's certificate");
    assert_eq!(handshake_signed(&key, &transcript, &signature), Ok(()));
    let mut other = transcript;
    other[0] ^= 1;
    assert_eq!(handshake_signed(&key, &other, &signature), Err(Problem::Signature));
    // The CA's key did not sign it.
    let ca_key = Certificate::read(&ca_der).and_then(|c| c.key()).expect("the CA's key");
    assert_eq!(handshake_signed(&ca_key, &transcript, &signature), Err(Problem::Signature));
    let _ = std::fs::remove_dir_all(d);
}

/// A TLS server's certificate only (RFC 5280 §4.2.1.3, 4.2.1.9, 4.2.1.12; RFC 8446 §4.4.2.2):
/// not a CA's unless it is the very one installed (a self-signed broker's); its key usage, where
/// given, for signatures; its extended key usage, where given, a server's.
#[test]
fn only_a_tls_servers_certificate_is_taken() {
    let d = dir("purpose");
    let ca_der = ca(&d, "ca", false);
    let now = soon();
    let san = "subjectAltName=DNS:broker.test\n";
    for (name, ext, expected) in [
        ("ca-true", "basicConstraints=critical,CA:TRUE\n", Some(Problem::Purpose)),
        ("encipher", "keyUsage=critical,keyEncipherment\n", Some(Problem::Purpose)),
        ("client", "extendedKeyUsage=clientAuth\n", Some(Problem::Purpose)),
        ("server", "keyUsage=critical,digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n", None),
    ] {
        let broker = issue(&d, name, "/CN=broker.test", &format!("{san}{ext}"), "ca", false);
        assert_eq!(check(&ca_der, &broker, "broker.test", now).err(), expected, "{name}");
    }
    // A self-signed broker's certificate (openssl's `req -x509`: CA:TRUE) installed as the CA.
    let own = self_signed(&d, "self", "/CN=broker.test", false, &["-addext", "subjectAltName=DNS:broker.test"]);
    assert!(check(&own, &own, "broker.test", now).is_ok());
    assert_eq!(check(&own, &own, "other.test", now).err(), Some(Problem::Name));
    let _ = std::fs::remove_dir_all(d);
}
