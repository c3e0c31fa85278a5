//! MQTT's settings in the web console's API (docs/mqtt.md, "Settings"; docs/web.md):
//! `GET /api/v1/mqtt` and `PUT /api/v1/mqtt`, both signed requests of a logged-in session (the
//! broker's address says where the module's values go: not for anyone), the change refused
//! while the factory password is in force (a module anyone may log in to would otherwise take
//! output commands from anyone's broker). A change is checked whole
//! (`remodaq_shared::mqtt::Config::check`), committed to flash as a record of its own
//! (`settings::key::MQTT`) from the administration's budget, and in force at once: the MQTT
//! service starts its session again with it. The CA certificate and the broker's credentials
//! are not these settings (never shown back).

use core::fmt::Write as _;
use core::net::Ipv4Addr;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embedded_storage_async::nor_flash::NorFlash;
use picoserve::response::StatusCode;
use remodaq_protocol::m8318::CHANNELS;
use remodaq_protocol::net::parse_ipv4;
use remodaq_protocol::web::{mqtt_credentials_of, MQTT_CREDENTIALS_LABEL, MQTT_CREDENTIALS_LEN, SESSION_ID_LEN};
use remodaq_protocol::x509::Certificate;
use remodaq_shared::json::Object;
use remodaq_shared::module::{commit_raw_record, commit_service_record, SettingsAccess};
use remodaq_shared::mqtt::{binding, der_of_pem, Config, Credentials, Invalid, CA_VERSION, SNTP_PORT};
use remodaq_shared::settings::key;

use crate::service::api::{Answer, Api, Json};
use crate::settings::unsealed;

/// Why a `PUT /api/v1/mqtt` body is refused.
#[derive(Debug, PartialEq, Eq)]
pub enum MqttError {
    /// Not a JSON object with every field, each of its kind.
    NotJson,
    /// This field's value is not usable.
    Field(&'static str),
}

/// The settings of a `PUT /api/v1/mqtt` body: every field of `GET`'s answer, each of its kind,
/// then checked whole ([`Config::check`]), the field at fault named.
pub fn config_of(body: &[u8]) -> Result<Config, MqttError> {
    let o = Object::parse(body).ok_or(MqttError::NotJson)?;
    let text = |name| o.str(name).ok_or(MqttError::NotJson);
    let flag = |name| o.bool(name).ok_or(MqttError::NotJson);
    let mut deadbands = [0u32; CHANNELS];
    let mut given = 0;
    for (i, band) in o.u32s("deadbands").ok_or(MqttError::NotJson)?.enumerate() {
        *deadbands.get_mut(i).ok_or(MqttError::Field("deadbands"))? = band.ok_or(MqttError::Field("deadbands"))?;
        given += 1;
    }
    if given != CHANNELS {
        return Err(MqttError::Field("deadbands"));
    }
    let config = Config {
        on: flag("on")?,
        broker: parse_ipv4(text("broker")?).ok_or(MqttError::Field("broker"))?,
        host: string(&o, "host")?,
        port: o.u16("port").ok_or(MqttError::Field("port"))?,
        client_id: string(&o, "client_id")?,
        tls: flag("tls")?,
        prefix: string(&o, "prefix")?,
        period_ms: o.u32("period_ms").ok_or(MqttError::Field("period_ms"))?,
        at_least_once: match o.u32("qos") {
            Some(0) => false,
            Some(1) => true,
            _ => return Err(MqttError::Field("qos")),
        },
        deadbands,
        on_change: flag("on_change")?,
        commands: flag("commands")?,
        sntp: [0; 4],
        sntp_port: SNTP_PORT,
    };
    // The time server: "" for none, `a.b.c.d` (port 123) or `a.b.c.d:port`.
    let sntp = text("sntp")?;
    let config = match sntp.split_once(':') {
        _ if sntp.is_empty() => config,
        Some((ip, port)) => Config {
            sntp: parse_ipv4(ip).ok_or(MqttError::Field("sntp"))?,
            sntp_port: port.parse().map_err(|_| MqttError::Field("sntp"))?,
            ..config
        },
        None => Config { sntp: parse_ipv4(sntp).ok_or(MqttError::Field("sntp"))?, ..config },
    };
    config.check().map_err(|Invalid(field)| MqttError::Field(field))?;
    Ok(config)
}

/// Member `name` as a string of at most `N` bytes.
fn string<const N: usize>(o: &Object<'_>, name: &'static str) -> Result<heapless::String<N>, MqttError> {
    heapless::String::try_from(o.str(name).ok_or(MqttError::NotJson)?).map_err(|_| MqttError::Field(name))
}

/// `config` as `GET /api/v1/mqtt` answers it (and `PUT` takes it).
fn write_config(out: &mut Json, c: &Config) {
    let _ = write!(
        out,
        "{{\"on\":{},\"broker\":\"{}\",\"host\":\"{}\",\"port\":{},\"client_id\":\"{}\",\"tls\":{},\"prefix\":\"{}\",\
         \"period_ms\":{},\"qos\":{},\"deadbands\":[",
        c.on,
        Ipv4Addr::from(c.broker),
        c.host,
        c.port,
        c.client_id,
        c.tls,
        c.prefix,
        c.period_ms,
        u8::from(c.at_least_once)
    );
    for (i, band) in c.deadbands.iter().enumerate() {
        let _ = write!(out, "{}{band}", if i > 0 { "," } else { "" });
    }
    let _ = write!(out, "],\"on_change\":{},\"commands\":{},\"sntp\":\"", c.on_change, c.commands);
    if c.sntp != [0; 4] {
        let _ = write!(out, "{}", Ipv4Addr::from(c.sntp));
        if c.sntp_port != SNTP_PORT {
            let _ = write!(out, ":{}", c.sntp_port);
        }
    }
    let _ = write!(out, "\"}}");
}

impl<R: RawMutex, M: remodaq_shared::modbus::RegisterMap + SettingsAccess, F: NorFlash> Api<'_, R, M, F> {
    /// `GET /api/v1/mqtt` (signed): MQTT's settings as stored (and in force), and whether a CA
    /// certificate and credentials are stored (never what they are).
    pub(super) async fn mqtt(&self, out: &mut Json) -> Answer {
        let (config, ca, credentials) = {
            let mut store = self.store.lock().await;
            let config: Config = store.service_record(key::MQTT).await;
            let ca = store.raw_record(key::MQTT_CA, CA_VERSION, |der| !der.is_empty()).await;
            let credentials: Credentials = store.service_record(key::MQTT_CREDENTIALS).await;
            (config, ca, !credentials.user.is_empty())
        };
        let a = Answer::new(out, StatusCode::OK);
        write_config(out, &config);
        // Into the object just written: its closing brace goes after these.
        out.text.pop();
        let _ = write!(out, ",\"ca\":{ca},\"credentials\":{credentials}}}");
        a
    }

    /// `PUT /api/v1/mqtt/ca` (signed, not with the factory password): `{"pem": "..."}`, the CA
    /// certificate the broker's chain must lead to (PEM, at most `MAX_CA` bytes as DER; an empty
    /// string removes it), decoded straight into the store's record and committed. A
    /// certificate the module's TLS cannot take (not one `remodaq_protocol::x509` reads: an RSA
    /// or P-384 CA, a key, a version 1 certificate) is refused here, 422 with why, rather than
    /// at every connection.
    pub(super) async fn set_mqtt_ca(&self, out: &mut Json, body: &[u8]) -> Answer {
        let Some(pem) = Object::parse(body).and_then(|o| o.str("pem")) else {
            return Answer::error(out, StatusCode::BAD_REQUEST, "expected {pem}", None);
        };
        let mut refused = None;
        let fill = |der: &mut [u8]| {
            if pem.is_empty() {
                return Some(0);
            }
            let Some(n) = der_of_pem(pem.as_bytes(), der) else {
                refused = Some("not a PEM certificate of at most 768 bytes: an ECDSA P-256 CA (an RSA one is larger)");
                return None;
            };
            match Certificate::read(der.get(..n)?) {
                Ok(_) => Some(n),
                Err(problem) => {
                    refused = Some(problem.what());
                    None
                }
            }
        };
        let result = commit_raw_record(self.store, key::MQTT_CA, CA_VERSION, fill).await;
        if let Some(why) = refused {
            return Answer::error(out, StatusCode::UNPROCESSABLE_ENTITY, why, Some("pem"));
        }
        crate::settings::committed(out, result)
    }

    /// `PUT /api/v1/mqtt/credentials` (signed, not with the factory password): the broker's user
    /// name and password sealed as a new password is (`{module, public, sealed}`, under the key
    /// `POST /api/v1/password/key` offered this session, `MQTT_CREDENTIALS_LABEL`): never in
    /// clear on the wire. Bound to the broker as stored (`binding`): store the settings and the
    /// CA first. An empty user name removes them.
    pub(super) async fn set_mqtt_credentials(
        &self,
        out: &mut Json,
        session: [u8; SESSION_ID_LEN],
        body: &[u8],
    ) -> Answer {
        let bytes = match unsealed::<MQTT_CREDENTIALS_LEN>(session, body, MQTT_CREDENTIALS_LABEL).await {
            Ok(bytes) => bytes,
            Err(why) => return why.answer(out, "the keys are 64 hex digits, the credentials 196"),
        };
        let Some((user, password)) = mqtt_credentials_of(&bytes) else {
            return Answer::error(
                out,
                StatusCode::UNPROCESSABLE_ENTITY,
                "not a user name and password",
                Some("sealed"),
            );
        };
        // Bound to the broker as stored now (its address, port, name and CA: `binding`).
        let bound = {
            let mut store = self.store.lock().await;
            let config: Config = store.service_record(key::MQTT).await;
            store.raw_record(key::MQTT_CA, CA_VERSION, |der| binding(&config, der)).await
        };
        let credentials = Credentials {
            user: heapless::String::try_from(user).unwrap_or_default(),
            password: heapless::String::try_from(password).unwrap_or_default(),
            binding: bound,
        };
        crate::settings::committed(out, commit_service_record(self.store, key::MQTT_CREDENTIALS, &credentials).await)
    }

    /// `PUT /api/v1/mqtt` (signed, not with the factory password): new MQTT settings, checked
    /// whole, stored, and in force at once.
    pub(super) async fn set_mqtt(&self, out: &mut Json, body: &[u8]) -> Answer {
        match config_of(body) {
            Ok(config) => crate::settings::committed(out, commit_service_record(self.store, key::MQTT, &config).await),
            Err(MqttError::NotJson) => Answer::error(
                out,
                StatusCode::BAD_REQUEST,
                "expected {on, broker, host, port, client_id, tls, prefix, period_ms, qos, deadbands, on_change, commands, sntp}",
                None,
            ),
            Err(MqttError::Field(field)) => {
                Answer::error(out, StatusCode::UNPROCESSABLE_ENTITY, "not a usable value", Some(field))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BODY: &str = r#"{"on":true,"broker":"192.168.0.10","host":"broker.plant","port":8883,"client_id":"",
        "tls":true,"prefix":"plant/line-2","period_ms":1000,"qos":1,"deadbands":[50,0,0,0,0,0,0,7],
        "on_change":true,"commands":false,"sntp":"192.168.0.1:1123"}"#;

    #[test]
    fn a_body_read_and_written_back() {
        let config = config_of(BODY.as_bytes()).expect("usable");
        assert_eq!(
            (config.broker, config.port, config.deadbands[0], config.deadbands[7]),
            ([192, 168, 0, 10], 8883, 50, 7)
        );
        assert_eq!(config.prefix.as_str(), "plant/line-2");
        let mut out = Json::default();
        write_config(&mut out, &config);
        assert_eq!(config_of(out.text.as_bytes()), Ok(config), "{}", out.text);
    }

    #[test]
    fn what_is_refused() {
        let with = |from: &str, to: &str| std::string::String::from(BODY).replacen(from, to, 1);
        for (body, want) in [
            (with(r#""qos":1"#, r#""qos":2"#), MqttError::Field("qos")),
            (with("[50,0,0,0,0,0,0,7]", "[50,0,0,0,0,0,0]"), MqttError::Field("deadbands")),
            (with("[50,0,0,0,0,0,0,7]", "[50,0,0,0,0,0,0,7,1]"), MqttError::Field("deadbands")),
            (with("[50,0,0,0,0,0,0,7]", "[50,0,0,0,0,0,0,-7]"), MqttError::Field("deadbands")),
            (with("192.168.0.10", "192.168.0"), MqttError::Field("broker")),
            (with("192.168.0.10", "224.0.0.1"), MqttError::Field("broker")),
            (with("1000", "50"), MqttError::Field("period_ms")),
            (with("plant/line-2", "plant/#"), MqttError::Field("prefix")),
            (with(r#""port":8883"#, r#""port":0"#), MqttError::Field("port")),
            (with(r#""on":true"#, r#""on":1"#), MqttError::NotJson),
            (with("192.168.0.1:1123", "192.168.0.1:0"), MqttError::Field("sntp")),
            (with("192.168.0.1:1123", "239.0.0.1"), MqttError::Field("sntp")),
            (with(r#""commands":false"#, r#""other":false"#), MqttError::NotJson),
        ] {
            assert_eq!(config_of(body.as_bytes()), Err(want), "{body}");
        }
    }
}
