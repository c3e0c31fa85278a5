//! The MQTT tab (issue #40, docs/mqtt.md): MQTT's settings through the module's web console
//! (`remodaq_client::web`: a login with the configuration password, which never crosses the
//! network), read into the form and stored from it, with the CA certificate (a PEM or DER file)
//! and the broker's user name and password (sealed on the way, never shown back).

use std::net::SocketAddr;

use eframe::egui::{self, Ui};
use remodaq_client::web::MqttSettings;
use zeroize::Zeroizing;

use super::password::Purpose;
use super::{field, tr, Utility};
use crate::worker::{Located, MqttChange};

/// The MQTT tab's fields, as typed.
#[derive(Default)]
pub(crate) struct MqttForm {
    /// The module's web console, `HOST[:PORT]` (empty: the module's address, port 80).
    console: String,
    /// The settings last read or stored (what the fields started from).
    loaded: Option<MqttSettings>,
    on: bool,
    broker: String,
    host: String,
    port: String,
    client_id: String,
    tls: bool,
    prefix: String,
    period_ms: String,
    qos1: bool,
    deadbands: String,
    on_change: bool,
    commands: bool,
    ca_file: String,
    user: String,
    password: Zeroizing<String>,
}

impl MqttForm {
    /// The fields from `s`, as read or stored.
    pub(crate) fn load(&mut self, s: MqttSettings) {
        self.on = s.on;
        self.broker = s.broker.clone();
        self.host = s.host.clone();
        self.port = s.port.to_string();
        self.client_id = s.client_id.clone();
        self.tls = s.tls;
        self.prefix = s.prefix.clone();
        self.period_ms = s.period_ms.to_string();
        self.qos1 = s.qos == 1;
        self.deadbands = s.deadbands.iter().map(u32::to_string).collect::<Vec<_>>().join(" ");
        self.on_change = s.on_change;
        self.commands = s.commands;
        self.loaded = Some(s);
    }

    /// The settings the fields say, or which field is not a number.
    fn settings(&self) -> Result<MqttSettings, &'static str> {
        let number = |text: &str, what: &'static str| text.trim().parse::<u32>().map_err(|_| what);
        let deadbands =
            self.deadbands.split_whitespace().map(|d| number(d, "Deadbands")).collect::<Result<Vec<_>, _>>()?;
        Ok(MqttSettings {
            on: self.on,
            broker: self.broker.trim().to_owned(),
            host: self.host.trim().to_owned(),
            port: u16::try_from(number(&self.port, "Port")?).map_err(|_| "Port")?,
            client_id: self.client_id.trim().to_owned(),
            tls: self.tls,
            prefix: self.prefix.trim().to_owned(),
            period_ms: number(&self.period_ms, "Period (ms)")?,
            qos: u8::from(self.qos1),
            deadbands,
            on_change: self.on_change,
            commands: self.commands,
            ca: false,
            credentials: false,
        })
    }

    /// The web console's address: the field, or the module's address on port 80.
    fn console(&self, m: &Located) -> Result<SocketAddr, String> {
        let given = self.console.trim();
        let text = if given.is_empty() { m.modbus.ip().to_string() } else { given.to_owned() };
        remodaq_client::modbus::resolve_on(&text, 80).map_err(|e| e.to_string())
    }
}

impl Utility {
    pub(super) fn mqtt_tab(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        let f = &mut self.mqtt;
        ui.heading("MQTT");
        ui.label(tr(lang, "Through the module's web console; not while the factory password is in force"));
        field(ui, tr(lang, "Web console"), &mut f.console, None, 200.0);
        ui.checkbox(&mut f.on, tr(lang, "Publish to the broker"));
        ui.horizontal(|ui| {
            field(ui, tr(lang, "Broker address"), &mut f.broker, None, 130.0);
            field(ui, tr(lang, "Port"), &mut f.port, None, 60.0);
        });
        ui.horizontal(|ui| {
            ui.checkbox(&mut f.tls, "TLS");
            field(ui, tr(lang, "Broker host name"), &mut f.host, None, 180.0);
        });
        ui.horizontal(|ui| {
            field(ui, tr(lang, "Client id"), &mut f.client_id, None, 160.0);
            field(ui, tr(lang, "Topic prefix"), &mut f.prefix, None, 220.0);
        });
        ui.horizontal(|ui| {
            field(ui, tr(lang, "Period (ms)"), &mut f.period_ms, None, 80.0);
            ui.checkbox(&mut f.qos1, tr(lang, "QoS 1 (at least once)"));
        });
        if m.found.model == "8318" {
            field(ui, tr(lang, "Deadbands"), &mut f.deadbands, None, 260.0);
        } else {
            ui.horizontal(|ui| {
                ui.checkbox(&mut f.on_change, tr(lang, "Publish on change"));
                ui.checkbox(&mut f.commands, tr(lang, "Take output commands"));
            });
        }
        if let Some(s) = &f.loaded {
            let stored = |b: bool| if b { tr(lang, "stored") } else { tr(lang, "none") };
            ui.label(format!(
                "{}: {}; {}: {}",
                tr(lang, "CA certificate"),
                stored(s.ca),
                tr(lang, "Broker credentials"),
                stored(s.credentials)
            ));
        }
        field(ui, tr(lang, "CA certificate file"), &mut f.ca_file, None, 320.0);
        ui.horizontal(|ui| {
            field(ui, tr(lang, "Broker user"), &mut f.user, None, 140.0);
            let l = ui.label(tr(lang, "Broker password"));
            ui.add(egui::TextEdit::singleline(&mut *f.password).password(true).desired_width(140.0)).labelled_by(l.id);
        });
        let (read, store) = ui
            .horizontal(|ui| {
                (
                    ui.button(tr(lang, "Read MQTT settings")).clicked(),
                    ui.button(tr(lang, "Store MQTT settings")).clicked(),
                )
            })
            .inner;
        if read {
            match self.mqtt.console(m) {
                Ok(web) => self.ask(Purpose::GetMqtt(web), m),
                Err(e) => self.say(e, true),
            }
        }
        if store {
            let change = self.mqtt.settings().map_err(|what| tr(lang, what).to_owned()).and_then(|settings| {
                let ca = match self.mqtt.ca_file.trim() {
                    "" => None,
                    file => Some(remodaq_client::web::pem_of_file(file).map_err(|e| e.to_string())?),
                };
                let user = self.mqtt.user.trim();
                let credentials =
                    (!user.is_empty()).then(|| (user.to_owned(), std::mem::take(&mut self.mqtt.password)));
                Ok(MqttChange { web: self.mqtt.console(m)?, settings, ca, credentials })
            });
            match change {
                Ok(change) => self.ask(Purpose::SetMqtt(Box::new(change)), m),
                Err(e) => self.say(format!("{}: {e}", tr(lang, "Not stored")), true),
            }
        }
    }
}
