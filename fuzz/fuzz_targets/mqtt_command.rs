//! MQTT's command parsing and settings (issue #40, docs/mqtt.md): arbitrary topics, payloads
//! and stored records never panic; a payload taken as a command writes what it says, re-read
//! from its canonical form; a topic taken as a command names that output's own topic; a prefix
//! taken as valid makes topics that read back; a stored record reads as settings that are off
//! or valid, and that store and read back the same; a CA's PEM decodes to a DER that fits, or
//! to nothing; credentials stored or sealed read back the same. `cargo +nightly fuzz run mqtt_command`
//! (from the repository root).
#![no_main]

use libfuzzer_sys::fuzz_target;
use remodaq_mqtt::command::{Command, MAX_COMMAND};
use remodaq_mqtt::config::Config;
use remodaq_mqtt::topics::{command_output, point, prefix_is_valid, Kind};
use remodaq_protocol::web::{mqtt_credentials, mqtt_credentials_of, MQTT_CREDENTIALS_LEN};
use remodaq_shared::mqtt::Credentials;
use remodaq_shared::settings::{decode_record, encode_record, MAX_RECORD};

fuzz_target!(|data: &[u8]| {
    // The whole input as a stored record of MQTT's settings.
    if let Some(config) = decode_record::<Config>(data) {
        assert!(!config.on || config.check().is_ok(), "{config:?}");
        let mut record = [0u8; MAX_RECORD];
        let n = encode_record(&config, &mut record).expect("settings that were read fit a record");
        assert_eq!(decode_record::<Config>(&record[..n]).as_ref(), Some(&config));
    }
    // The whole input as a CA certificate's PEM (`PUT /api/v1/mqtt/ca`): a DER that fits, or
    // nothing; as stored credentials and as sealed ones opened.
    let mut der = [0u8; remodaq_shared::mqtt::MAX_CA];
    if let Some(n) = remodaq_shared::mqtt::der_of_pem(data, &mut der) {
        assert!(n <= der.len() && der[0] == 0x30);
    }
    if let Some(c) = decode_record::<Credentials>(data) {
        let mut record = [0u8; MAX_RECORD];
        let n = encode_record(&c, &mut record).expect("credentials that were read fit a record");
        assert_eq!(decode_record::<Credentials>(&record[..n]).as_ref(), Some(&c));
    }
    if let Ok(sealed) = <[u8; MQTT_CREDENTIALS_LEN]>::try_from(data.get(..MQTT_CREDENTIALS_LEN).unwrap_or(&[])) {
        if let Some((user, password)) = mqtt_credentials_of(&sealed) {
            let again = mqtt_credentials(user, password).expect("what was read fits");
            assert_eq!(mqtt_credentials_of(&again), Some((user, password)));
        }
    }
    let Some((&split, rest)) = data.split_first() else { return };
    let (text, payload) = rest.split_at(usize::from(split).min(rest.len()));
    let text = String::from_utf8_lossy(text);
    let (prefix, topic) = text.split_once('\n').unwrap_or((&text, ""));

    match Command::parse(payload) {
        Ok(command) => {
            assert!(payload.len() <= MAX_COMMAND);
            let canonical = match command {
                Command::Level(level) => format!("{{\"level\":{level}}}"),
                Command::Pulse { low, high, count } => format!(
                    "{{\"low_ms\":{}.{},\"high_ms\":{}.{},\"count\":{count}}}",
                    low / 10,
                    low % 10,
                    high / 10,
                    high % 10
                ),
            };
            assert_eq!(Command::parse(canonical.as_bytes()), Ok(command), "{canonical}");
            for n in 0..6 {
                let requests = command.requests(n);
                let expected = if matches!(command, Command::Level(_)) { 2 } else { 5 };
                assert_eq!(requests.len(), expected);
                assert!(requests.iter().all(|r| matches!(r.bytes().len(), 5 | 10)));
            }
        }
        Err(_) => {}
    }

    if let Some(n) = command_output(prefix, topic, 6) {
        assert!(n < 6);
        assert_eq!(format!("{}/set", point(prefix, Kind::Do, n)), topic);
    }
    if prefix_is_valid(prefix) {
        for n in 0..6 {
            let t = format!("{}/set", point(prefix, Kind::Do, n));
            assert_eq!(command_output(prefix, &t, 6), Some(n), "{t}");
        }
    }
});
