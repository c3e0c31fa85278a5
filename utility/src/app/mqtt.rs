//! The MQTT tab (issue #40, docs/mqtt.md): MQTT's settings through the module's web console
//! (`remodaq_client::web`: a login with the configuration password, which never crosses the
//! network), read into the form and stored from it, with the CA certificate (a PEM or DER file)
//! and the broker's user name and password (sealed on the way, never shown back).

use eframe::egui::{self, Ui};

use super::password::Purpose;
use super::{field, tr, Utility};
use crate::worker::{Located, MqttChange};

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
        field(ui, tr(lang, "Time server (SNTP)"), &mut f.sntp, None, 160.0);
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
