//! `remodaq mqtt show|set MODULE`: MQTT's settings through the module's web console API
//! (`remodaq_client::web`, docs/mqtt.md), after a login with the configuration password (no
//! password on the wire). `set` changes only the settings given, the others kept as stored.

use std::net::SocketAddr;

use remodaq_client::web::{MqttSettings, Session};
use remodaq_client::Error;

/// The changes `remodaq mqtt set` was given.
#[derive(clap::Args, Default)]
pub struct Changes {
    /// Connect to the broker.
    #[arg(long, conflicts_with = "off")]
    pub on: bool,
    /// Do not connect.
    #[arg(long)]
    pub off: bool,
    /// The broker's IPv4 address.
    #[arg(long)]
    pub broker: Option<std::net::Ipv4Addr>,
    /// The broker's host name, which its certificate must name (TLS).
    #[arg(long)]
    pub host: Option<String>,
    /// The broker's port (8883 for TLS, 1883 plain).
    #[arg(long)]
    pub port: Option<u16>,
    /// The client identifier (1-23 of 0-9 A-Z a-z - _; "" for remodaq-<mac>).
    #[arg(long)]
    pub client_id: Option<String>,
    /// TLS to the broker: on or off.
    #[arg(long, value_parser = on_off)]
    pub tls: Option<bool>,
    /// The topics' prefix ("" for remodaq/<model>/<mac>).
    #[arg(long)]
    pub prefix: Option<String>,
    /// Each point at least once per this many ms (100 to 3600000).
    #[arg(long)]
    pub period_ms: Option<u32>,
    /// QoS of the publications: 0 or 1.
    #[arg(long)]
    pub qos: Option<u8>,
    /// An 8318 channel's deadband, CHANNEL=THOUSANDTHS of its unit (repeatable).
    #[arg(long, value_parser = deadband)]
    pub deadband: Vec<(usize, u32)>,
    /// The 8350's points on any change: on or off.
    #[arg(long, value_parser = on_off)]
    pub on_change: Option<bool>,
    /// The 8350 takes output commands from the broker: on or off.
    #[arg(long, value_parser = on_off)]
    pub commands: Option<bool>,
    /// The time server (SNTP) the modules take the time of day from: ADDR or ADDR:PORT ("" none).
    #[arg(long)]
    pub sntp: Option<String>,
    /// The CA certificate the broker's chain must lead to: a PEM or DER file, or "none".
    #[arg(long, value_name = "FILE")]
    pub ca: Option<String>,
    /// The broker's user name; its password is asked for without echo (or REMODAQ_MQTT_PASSWORD).
    /// Both reach the module sealed and are only ever sent to the broker inside TLS; "" removes
    /// them.
    #[arg(long)]
    pub user: Option<String>,
}

fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("`{s}`: on or off")),
    }
}

fn deadband(s: &str) -> Result<(usize, u32), String> {
    let (channel, value) = s.split_once('=').ok_or_else(|| format!("`{s}`: CHANNEL=THOUSANDTHS"))?;
    match (channel.parse::<usize>(), value.parse::<u32>()) {
        (Ok(c), Ok(v)) if c < 8 => Ok((c, v)),
        _ => Err(format!("`{s}`: a channel 0-7 and a whole number of thousandths")),
    }
}

impl Changes {
    /// `settings` with these changes.
    pub fn apply(&self, settings: &mut MqttSettings) {
        if self.on || self.off {
            settings.on = self.on;
        }
        if let Some(broker) = self.broker {
            settings.broker = broker.to_string();
        }
        let text = |given: &Option<String>, field: &mut String| {
            if let Some(v) = given {
                v.clone_into(field);
            }
        };
        text(&self.host, &mut settings.host);
        text(&self.client_id, &mut settings.client_id);
        text(&self.prefix, &mut settings.prefix);
        text(&self.sntp, &mut settings.sntp);
        settings.port = self.port.unwrap_or(settings.port);
        settings.tls = self.tls.unwrap_or(settings.tls);
        settings.period_ms = self.period_ms.unwrap_or(settings.period_ms);
        settings.qos = self.qos.unwrap_or(settings.qos);
        for &(channel, value) in &self.deadband {
            if let Some(band) = settings.deadbands.get_mut(channel) {
                *band = value;
            }
        }
        settings.on_change = self.on_change.unwrap_or(settings.on_change);
        settings.commands = self.commands.unwrap_or(settings.commands);
    }
}

/// The console's address: MODULE as `HOST` (port 80) or `HOST:PORT`.
fn console(module: &str) -> Result<SocketAddr, Error> {
    remodaq_client::modbus::resolve_on(module, 80)
}

fn print(settings: &MqttSettings, json: bool) -> Result<(), Error> {
    if json {
        let mut shown = serde_json::to_value(settings).map_err(|e| Error::Other(e.to_string()))?;
        shown["ca"] = settings.ca.into();
        shown["credentials"] = settings.credentials.into();
        println!("{shown}");
        return Ok(());
    }
    let or = |text: &str, default: &'static str| if text.is_empty() { default.to_owned() } else { text.to_owned() };
    let yes = |b: bool| if b { "on" } else { "off" };
    println!("MQTT:       {}", yes(settings.on));
    println!(
        "broker:     {}:{} (host name {}, TLS {})",
        settings.broker,
        settings.port,
        or(&settings.host, "none"),
        yes(settings.tls)
    );
    println!("client id:  {}", or(&settings.client_id, "remodaq-<mac>"));
    println!("prefix:     {}", or(&settings.prefix, "remodaq/<model>/<mac>"));
    println!("period:     {} ms, QoS {}", settings.period_ms, settings.qos);
    let bands: Vec<String> = settings.deadbands.iter().map(u32::to_string).collect();
    println!("deadbands:  {} (8318, thousandths of each channel's unit)", bands.join(" "));
    println!("on change:  {} (8350)", yes(settings.on_change));
    println!("commands:   {} (8350)", yes(settings.commands));
    println!("time:       {}", or(&settings.sntp, "no time server"));
    let stored = |b: bool| if b { "stored" } else { "none" };
    println!("CA:         {}; credentials: {} (never shown)", stored(settings.ca), stored(settings.credentials));
    Ok(())
}

/// `remodaq mqtt show MODULE`.
pub async fn show(module: &str, password: &str, json: bool) -> Result<(), Error> {
    let mut session = Session::log_in(console(module)?, password).await?;
    print(&session.mqtt().await?, json)
}

/// `remodaq mqtt set MODULE ...`: the stored settings with `changes`, stored, then the CA
/// certificate and the credentials when given; then shown.
pub async fn set(module: &str, password: &str, changes: &Changes, json: bool) -> Result<(), Error> {
    // Read before anything is changed: a file that cannot be used changes nothing.
    let ca = match changes.ca.as_deref() {
        None => None,
        Some("none") => Some(String::new()),
        Some(file) => Some(remodaq_client::web::pem_of_file(file)?),
    };
    let broker_password = match changes.user.as_deref() {
        None | Some("") => String::new(),
        Some(_) => match std::env::var("REMODAQ_MQTT_PASSWORD") {
            Ok(p) => p,
            Err(_) => rpassword::prompt_password("the broker's password: ").map_err(|e| {
                Error::Other(format!(
                    "no broker password given and none could be asked for ({e}): set REMODAQ_MQTT_PASSWORD"
                ))
            })?,
        },
    };
    let mut session = Session::log_in(console(module)?, password).await?;
    let mut settings = session.mqtt().await?;
    changes.apply(&mut settings);
    session.set_mqtt(&settings).await?;
    if let Some(pem) = ca {
        session.set_mqtt_ca(&pem).await?;
    }
    if let Some(user) = changes.user.as_deref() {
        session.set_mqtt_credentials(user, &broker_password).await?;
    }
    print(&session.mqtt().await?, json)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn changes_apply_to_the_given_fields_only() {
        let mut s = MqttSettings {
            on: false,
            broker: "0.0.0.0".into(),
            host: String::new(),
            port: 8883,
            client_id: String::new(),
            tls: true,
            prefix: String::new(),
            period_ms: 10_000,
            qos: 1,
            deadbands: vec![0; 8],
            on_change: true,
            commands: false,
            sntp: String::new(),
            ca: false,
            credentials: false,
        };
        let changes = Changes {
            on: true,
            broker: Some([192, 168, 0, 10].into()),
            tls: Some(false),
            port: Some(1883),
            deadband: vec![(7, 50)],
            ..Changes::default()
        };
        changes.apply(&mut s);
        assert_eq!((s.on, s.broker.as_str(), s.tls, s.port, s.deadbands[7]), (true, "192.168.0.10", false, 1883, 50));
        assert_eq!((s.period_ms, s.commands, s.prefix.as_str()), (10_000, false, ""), "the others kept");
        assert_eq!(deadband("8=1"), Err("`8=1`: a channel 0-7 and a whole number of thousandths".into()));
        assert_eq!(console("10.0.0.5").ok(), Some(SocketAddr::from(([10, 0, 0, 5], 80))));
        assert_eq!(console("10.0.0.5:8080").ok(), Some(SocketAddr::from(([10, 0, 0, 5], 8080))));
    }
}
