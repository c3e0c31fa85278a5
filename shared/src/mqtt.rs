//! MQTT's settings (docs/mqtt.md, "Settings"), as a record of the settings store beside the
//! module's (`settings::key::MQTT`, a [`Schema`] of its own): the broker, the session, the
//! topics and what is published. Here, below the services, so that every service that sets
//! them (the web console) and the MQTT service that uses them (services/mqtt) share one
//! definition and one check. The CA certificate and the credentials are records of their own
//! (they do not fit this one, and are never shown back). Checked whole before a commit
//! ([`Config::check`]); a stored field that is not valid reads as its default
//! ([`Schema::decode`]).

use remodaq_protocol::m8318::CHANNELS;

use crate::settings::{RecordReader, RecordWriter, Schema};

/// Signalled when MQTT's settings were committed (`module::commit_service_record`): the MQTT
/// service ends its session and starts again with them.
pub static CHANGED: embassy_sync::signal::Signal<embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex, ()> =
    embassy_sync::signal::Signal::new();

/// The shortest and the longest publication period, ms (issue #40: 100 ms to 1 h).
pub const PERIOD_MS: core::ops::RangeInclusive<u32> = 100..=3_600_000;

/// The longest topic prefix, bytes.
pub const MAX_PREFIX: usize = 64;

/// Whether `prefix` can stand before the module's topics: 1 to [`MAX_PREFIX`] bytes of
/// printable ASCII, no wildcard (`+`, `#`: a topic name may not hold one, MQTT 5 §4.7.1), not
/// starting with `$` (the broker's own topics, §4.7.2) or `/`, no empty level and no `/` at the
/// end (every topic adds `/` and its own levels).
pub fn prefix_is_valid(prefix: &str) -> bool {
    !prefix.is_empty()
        && prefix.len() <= MAX_PREFIX
        && prefix.bytes().all(|b| (b' '..=b'~').contains(&b) && b != b'+' && b != b'#')
        && !prefix.starts_with('$')
        && prefix.split('/').all(|level| !level.is_empty())
}

/// The longest broker host name (TLS checks the broker's certificate against it).
pub const MAX_HOST: usize = 64;
/// The longest client identifier every broker takes (MQTT 5 §3.1.3.1).
pub const MAX_CLIENT_ID: usize = 23;

/// MQTT's settings.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Config {
    /// Whether the module connects at all (off by default).
    pub on: bool,
    /// The broker's IPv4 address.
    pub broker: [u8; 4],
    /// The broker's host name, which its certificate must name (TLS).
    pub host: heapless::String<MAX_HOST>,
    /// The broker's TCP port.
    pub port: u16,
    /// The client identifier; empty: `remodaq-<mac>`.
    pub client_id: heapless::String<MAX_CLIENT_ID>,
    /// TLS to the broker.
    pub tls: bool,
    /// The topics' prefix; empty: `remodaq/<model>/<mac>`.
    pub prefix: heapless::String<{ MAX_PREFIX }>,
    /// Each point at least once per this, ms.
    pub period_ms: u32,
    /// QoS 1 (else 0).
    pub at_least_once: bool,
    /// The 8318's deadbands, thousandths of each channel's unit.
    pub deadbands: [u32; CHANNELS],
    /// The 8350's points on any change (else on the period alone).
    pub on_change: bool,
    /// The 8350's output commands taken.
    pub commands: bool,
    /// The time server (SNTP) the embassy-net boards ask the time of day (a certificate's
    /// validity, the payloads' `time`); 0.0.0.0: none.
    pub sntp: [u8; 4],
    /// Its UDP port.
    pub sntp_port: u16,
}

/// A setting that is not valid, by name (as the web console's API names its fields).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Invalid(pub &'static str);

const TAG_ON: u8 = 1;
const TAG_BROKER: u8 = 2;
const TAG_HOST: u8 = 3;
const TAG_PORT: u8 = 4;
const TAG_CLIENT_ID: u8 = 5;
const TAG_TLS: u8 = 6;
const TAG_PREFIX: u8 = 7;
const TAG_PERIOD: u8 = 8;
const TAG_QOS: u8 = 9;
const TAG_DEADBANDS: u8 = 10;
const TAG_ON_CHANGE: u8 = 11;
const TAG_COMMANDS: u8 = 12;
const TAG_SNTP: u8 = 13;
const TAG_SNTP_PORT: u8 = 14;

/// SNTP's port (RFC 4330), the default.
pub const SNTP_PORT: u16 = 123;

/// MQTT over TLS's port (IANA), the default.
pub const TLS_PORT: u16 = 8883;

impl Config {
    /// Whether every setting is valid: a port, a client id of 1-23 of `[0-9A-Za-z_-]` or none,
    /// a prefix [`prefix_is_valid`] or none, a period of 100 ms to 1 h, a host name of
    /// letters, digits, `-` and `.` (needed on with TLS, whose check names the broker), a broker
    /// address when on: not 0.0.0.0, multicast or broadcast (a loopback one serves a simulator),
    /// a time server that is none or no multicast or broadcast address, on a port.
    pub fn check(&self) -> Result<(), Invalid> {
        let id_ok = self.client_id.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
        let host_ok = self.host.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'.');
        if self.port == 0 {
            Err(Invalid("port"))
        } else if !id_ok {
            Err(Invalid("client_id"))
        } else if !self.prefix.is_empty() && !prefix_is_valid(&self.prefix) {
            Err(Invalid("prefix"))
        } else if !PERIOD_MS.contains(&self.period_ms) {
            Err(Invalid("period_ms"))
        } else if !host_ok || (self.on && self.tls && self.host.is_empty()) {
            Err(Invalid("host"))
        } else if self.on && (self.broker == [0; 4] || self.broker[0] >= 224) {
            Err(Invalid("broker"))
        } else if self.sntp[0] >= 224 || self.sntp_port == 0 {
            Err(Invalid("sntp"))
        } else {
            Ok(())
        }
    }
}

fn string<const N: usize>(r: &RecordReader<'_>, tag: u8) -> Option<heapless::String<N>> {
    let bytes = r.get(tag)?;
    let text = core::str::from_utf8(bytes).ok()?;
    heapless::String::try_from(text).ok()
}

fn flag(r: &RecordReader<'_>, tag: u8) -> Option<bool> {
    match r.get(tag)? {
        [0] => Some(false),
        [1] => Some(true),
        _ => None,
    }
}

impl Schema for Config {
    const VERSION: u8 = 1;

    fn defaults() -> Self {
        Self {
            on: false,
            broker: [0; 4],
            host: heapless::String::new(),
            port: TLS_PORT,
            client_id: heapless::String::new(),
            tls: true,
            prefix: heapless::String::new(),
            period_ms: 10_000,
            at_least_once: true,
            deadbands: [0; CHANNELS],
            on_change: true,
            commands: false,
            sntp: [0; 4],
            sntp_port: SNTP_PORT,
        }
    }

    /// Off: settings that cannot be read never connect anywhere.
    fn unreadable() -> Self {
        Self::defaults()
    }

    fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put(TAG_ON, &[u8::from(self.on)]);
        w.put(TAG_BROKER, &self.broker);
        w.put(TAG_HOST, self.host.as_bytes());
        w.put_u16(TAG_PORT, self.port);
        w.put(TAG_CLIENT_ID, self.client_id.as_bytes());
        w.put(TAG_TLS, &[u8::from(self.tls)]);
        w.put(TAG_PREFIX, self.prefix.as_bytes());
        w.put_u32(TAG_PERIOD, self.period_ms);
        w.put(TAG_QOS, &[u8::from(self.at_least_once)]);
        let mut deadbands = [0u8; 4 * CHANNELS];
        for (out, d) in deadbands.chunks_mut(4).zip(self.deadbands) {
            out.copy_from_slice(&d.to_le_bytes());
        }
        w.put(TAG_DEADBANDS, &deadbands);
        w.put(TAG_ON_CHANGE, &[u8::from(self.on_change)]);
        w.put(TAG_COMMANDS, &[u8::from(self.commands)]);
        w.put(TAG_SNTP, &self.sntp);
        w.put_u16(TAG_SNTP_PORT, self.sntp_port);
    }

    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        let d = Self::defaults();
        let mut c = Self {
            on: flag(r, TAG_ON).unwrap_or(d.on),
            broker: r.array(TAG_BROKER).unwrap_or(d.broker),
            host: string(r, TAG_HOST).unwrap_or(d.host.clone()),
            port: r.u16(TAG_PORT).unwrap_or(d.port),
            client_id: string(r, TAG_CLIENT_ID).unwrap_or(d.client_id.clone()),
            tls: flag(r, TAG_TLS).unwrap_or(d.tls),
            prefix: string(r, TAG_PREFIX).unwrap_or(d.prefix.clone()),
            period_ms: r.u32(TAG_PERIOD).unwrap_or(d.period_ms),
            at_least_once: flag(r, TAG_QOS).unwrap_or(d.at_least_once),
            deadbands: r
                .array::<{ 4 * CHANNELS }>(TAG_DEADBANDS)
                .map(|b| {
                    core::array::from_fn(|i| u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]))
                })
                .unwrap_or(d.deadbands),
            on_change: flag(r, TAG_ON_CHANGE).unwrap_or(d.on_change),
            commands: flag(r, TAG_COMMANDS).unwrap_or(d.commands),
            sntp: r.array(TAG_SNTP).unwrap_or(d.sntp),
            sntp_port: r.u16(TAG_SNTP_PORT).unwrap_or(d.sntp_port),
        };
        // A stored record that is not valid whole is not used: off (never a connection made on
        // half a configuration).
        if c.check().is_err() {
            c = Self { on: false, ..c };
        }
        c
    }
}

/// The longest CA certificate, DER bytes (a raw record, `settings::key::MQTT_CA`).
pub const MAX_CA: usize = crate::settings::MAX_RAW;
/// The CA certificate record's version.
pub const CA_VERSION: u8 = 1;

/// The DER of the first certificate in `pem` (`-----BEGIN CERTIFICATE-----`, base64, `-----END`),
/// written into `out`; how many bytes, or `None` when there is none or it does not fit. The
/// base64 may be broken by whitespace: the file's lines, or spaces where they were joined (the
/// web console's JSON strings have no escapes).
pub fn der_of_pem(pem: &[u8], out: &mut [u8]) -> Option<usize> {
    const BEGIN: &[u8] = b"-----BEGIN CERTIFICATE-----";
    let start = pem.windows(BEGIN.len()).position(|w| w == BEGIN)? + BEGIN.len();
    let body = &pem[start..];
    let end = body.windows(5).position(|w| w == b"-----")?;
    let (mut acc, mut bits, mut n, mut padded) = (0u32, 0u32, 0usize, false);
    for &c in &body[..end] {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' => {
                padded = true;
                continue;
            }
            b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return None,
        };
        if padded {
            return None;
        }
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            *out.get_mut(n)? = (acc >> bits) as u8;
            n += 1;
        }
    }
    // A certificate is a DER SEQUENCE.
    (n > 0 && out[0] == 0x30).then_some(n)
}

/// The longest user name and password for the broker, bytes.
pub const MAX_USER: usize = remodaq_protocol::web::MQTT_USER_MAX;
/// See [`MAX_USER`].
pub const MAX_PASSWORD: usize = remodaq_protocol::web::MQTT_PASSWORD_MAX;

/// The broker's user name and password (`settings::key::MQTT_CREDENTIALS`): sent only inside
/// TLS, only to the broker they were stored for ([`binding`]), never shown back. An empty user
/// name: none (anonymous).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Credentials {
    /// The user name.
    pub user: heapless::String<MAX_USER>,
    /// The password.
    pub password: heapless::String<MAX_PASSWORD>,
    /// The broker they were stored for ([`binding`]): whoever changes the broker's address,
    /// name or CA afterwards (the configuration password's holder) does not get them sent to
    /// his own broker; they must be stored again.
    pub binding: [u8; 8],
}

/// Which broker credentials are for: the first 8 bytes of HMAC-SHA-256 under an all-zero key of
/// tag("RDAQ mqtt binding"), the broker's address, port (little-endian), host name and CA
/// certificate (DER).
pub fn binding(config: &Config, ca: &[u8]) -> [u8; 8] {
    let port = config.port.to_le_bytes();
    let parts: [&[u8]; 5] =
        [remodaq_protocol::web::MQTT_BINDING_LABEL, &config.broker, &port, config.host.as_bytes(), ca];
    let mac = remodaq_protocol::auth::hmac(&[0; 32], &parts);
    let mut out = [0u8; 8];
    out.copy_from_slice(&mac[..8]);
    out
}

const TAG_USER: u8 = 1;
const TAG_PASSWORD: u8 = 2;
const TAG_BINDING: u8 = 3;

impl Schema for Credentials {
    const VERSION: u8 = 1;

    fn defaults() -> Self {
        Self::default()
    }

    /// None: a module whose credentials cannot be read connects with none (and a broker that
    /// wants them refuses it).
    fn unreadable() -> Self {
        Self::default()
    }

    fn encode(&self, w: &mut RecordWriter<'_>) {
        w.put(TAG_USER, self.user.as_bytes());
        w.put(TAG_PASSWORD, self.password.as_bytes());
        w.put(TAG_BINDING, &self.binding);
    }

    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        Self {
            user: string(r, TAG_USER).unwrap_or_default(),
            password: string(r, TAG_PASSWORD).unwrap_or_default(),
            binding: r.array(TAG_BINDING).unwrap_or_default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::{decode_record, encode_record, MAX_RECORD};

    fn on() -> Config {
        Config {
            on: true,
            broker: [192, 168, 0, 10],
            host: heapless::String::try_from("broker.plant.example").unwrap(),
            client_id: heapless::String::try_from("rdaq-line-2").unwrap(),
            prefix: heapless::String::try_from("plant/line-2/daq").unwrap(),
            period_ms: 1_000,
            deadbands: [50, 0, 0, 0, 0, 0, 0, 1_000_000],
            commands: true,
            ..Config::defaults()
        }
    }

    #[test]
    fn off_by_default_and_a_round_trip() {
        let d = Config::defaults();
        assert!(!d.on && !d.commands && d.tls && d.port == 8883, "off, TLS, no commands: {d:?}");
        assert_eq!(d.check(), Ok(()));
        let mut record = [0u8; MAX_RECORD];
        let longest = Config {
            host: heapless::String::try_from("h".repeat(MAX_HOST).as_str()).unwrap(),
            client_id: heapless::String::try_from("c".repeat(MAX_CLIENT_ID).as_str()).unwrap(),
            prefix: heapless::String::try_from("p".repeat(MAX_PREFIX).as_str()).unwrap(),
            ..on()
        };
        for c in [d, on(), longest] {
            let n = encode_record(&c, &mut record).expect("fits a record");
            assert_eq!(decode_record::<Config>(&record[..n]), Some(c));
        }
    }

    /// A PEM's DER, as a file has it and with its lines joined by spaces; what is not one.
    #[test]
    fn a_certificate_from_pem() {
        // 30 03 02 01 01: SEQUENCE { INTEGER 1 }, base64 "MAMCAQE=".
        let mut out = [0u8; 8];
        for pem in [
            &b"-----BEGIN CERTIFICATE-----\nMAMC\nAQE=\n-----END CERTIFICATE-----\n"[..],
            b"-----BEGIN CERTIFICATE----- MAMCAQE= -----END CERTIFICATE-----",
        ] {
            assert_eq!(der_of_pem(pem, &mut out), Some(5), "{}", std::string::String::from_utf8_lossy(pem));
            assert_eq!(out[..5], [0x30, 3, 2, 1, 1]);
        }
        for junk in [
            &b"MAMCAQE="[..],
            b"-----BEGIN CERTIFICATE-----\nMA*CAQE=\n-----END CERTIFICATE-----",
            b"-----BEGIN CERTIFICATE-----\nAgMCAQE=\n-----END CERTIFICATE-----",
            b"-----BEGIN CERTIFICATE-----\nMAMCAQEAAAAAAAAA\n-----END CERTIFICATE-----",
        ] {
            assert_eq!(der_of_pem(junk, &mut out), None, "{}", std::string::String::from_utf8_lossy(junk));
        }
    }

    /// The credentials' round trip; empty when nothing was stored.
    #[test]
    fn credentials_round_trip() {
        let mut record = [0u8; MAX_RECORD];
        let c = Credentials {
            user: heapless::String::try_from("u".repeat(MAX_USER).as_str()).unwrap(),
            password: heapless::String::try_from("p".repeat(MAX_PASSWORD).as_str()).unwrap(),
            binding: [7; 8],
        };
        let n = encode_record(&c, &mut record).expect("fits a record");
        assert_eq!(decode_record::<Credentials>(&record[..n]), Some(c));
        assert_eq!(decode_record::<Credentials>(&[0x5D, 0]), Some(Credentials::default()));
    }

    /// Docs/mqtt.md's ranges.
    #[test]
    fn what_is_not_valid() {
        let cases: [(Config, &str); 10] = [
            (Config { sntp: [224, 0, 0, 1], ..on() }, "sntp"),
            (Config { sntp_port: 0, ..on() }, "sntp"),
            (Config { port: 0, ..on() }, "port"),
            (Config { client_id: heapless::String::try_from("a b").unwrap(), ..on() }, "client_id"),
            (Config { prefix: heapless::String::try_from("a/#").unwrap(), ..on() }, "prefix"),
            (Config { period_ms: 99, ..on() }, "period_ms"),
            (Config { period_ms: 3_600_001, ..on() }, "period_ms"),
            (Config { host: heapless::String::new(), ..on() }, "host"),
            (Config { broker: [0; 4], ..on() }, "broker"),
            (Config { broker: [224, 0, 0, 1], ..on() }, "broker"),
        ];
        for (c, field) in cases {
            assert_eq!(c.check(), Err(Invalid(field)), "{c:?}");
        }
        assert_eq!(Config { host: heapless::String::new(), tls: false, ..on() }.check(), Ok(()), "no name without TLS");
        assert_eq!(Config { period_ms: 100, ..on() }.check(), Ok(()));
        assert_eq!(Config { period_ms: 3_600_000, ..on() }.check(), Ok(()));
    }

    /// A record written by someone else's hand: a field not valid reads as its default, and a
    /// configuration not valid whole is off.
    #[test]
    fn a_stored_record_not_valid_is_off() {
        let mut record = [0u8; MAX_RECORD];
        let n = encode_record(&Config { period_ms: 5, ..on() }, &mut record).unwrap();
        let read = decode_record::<Config>(&record[..n]).unwrap();
        assert!(!read.on, "{read:?}");
        // A flag that is neither 0 nor 1: its default.
        let mut fields = std::vec![TAG_TLS, 1, 7, TAG_COMMANDS, 1, 2];
        fields.extend_from_slice(&[TAG_PORT, 2, 0x5B, 0x07]);
        let c = Config::decode(1, &RecordReader::default_for_tests(&fields));
        assert_eq!((c.tls, c.commands, c.port), (true, false, 1883));
    }
}
