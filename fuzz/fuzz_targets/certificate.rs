//! The broker's certificate as MQTT's TLS reads it (`remodaq_mqtt::certificate`, docs/mqtt.md):
//! arbitrary bytes as a certificate, as an ECDSA signature's DER, and as the broker's
//! certificate under a CA (the seeds': openssl's) never panic; a certificate read takes no byte
//! after its end; one that reads is checked against itself as its own CA, each check answering.
//! `cargo +nightly fuzz run certificate` (from the repository root).
#![no_main]

use libfuzzer_sys::fuzz_target;
use remodaq_mqtt::certificate::{check, handshake_signed, signature, Certificate, Keys};

/// The seeds' CA (fuzz/seeds/certificate/ca.der: `openssl req -x509` with a P-256 key).
const CA: &[u8] = include_bytes!("../seeds/certificate/ca.der");

fuzz_target!(|data: &[u8]| {
    if let Ok(certificate) = Certificate::read(data) {
        let mut longer = data.to_vec();
        longer.push(0);
        assert!(Certificate::read(&longer).is_err(), "a byte after the certificate taken");
        let _ = certificate.valid_at(0);
        let _ = certificate.valid_at(u64::MAX);
        let _ = certificate.no_unknown_critical();
        let _ = certificate.serves_tls(false);
        let _ = certificate.serves_tls(true);
        let _ = certificate.names("broker.test");
        let _ = certificate.names("mqtt.plant.test");
        let _ = certificate.signed_by(&certificate);
        if let Ok(key) = certificate.key() {
            let _ = handshake_signed(&key, &[7; 32], data);
        }
    }
    let _ = signature(data);
    // 2027-01-01 (`date -u -d 2027-01-01 +%s`), within the seeds' validity (2026-12-06, ten years).
    let _ = check(CA, data, "broker.test", 1_798_761_600);
});
