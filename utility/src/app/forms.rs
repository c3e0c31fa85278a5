//! What the window keeps of its forms between frames: the Network Settings and MQTT tabs'
//! fields as typed, and the password dialog with what the password is asked for.

use std::net::SocketAddr;
use std::path::PathBuf;

use eframe::egui;
use remodaq_client::web::MqttSettings;
use remodaq_protocol::access::AllowList;
use zeroize::Zeroizing;

use crate::worker::Located;

/// The fields of the Network Settings tab, as typed.
#[derive(Default)]
pub(super) struct NetForm {
    pub(super) ip: String,
    pub(super) mask: String,
    pub(super) gateway: String,
    pub(super) port: String,
}

/// What a password is asked for.
#[derive(Clone, Debug)]
pub(super) enum Purpose {
    SetNetwork(remodaq_client::lan::NetChange),
    Restart,
    SetPassword(Zeroizing<String>),
    GetAccess,
    SetAccess(AllowList),
    Update(PathBuf),
    GetMqtt(std::net::SocketAddr),
    SetMqtt(Box<crate::worker::MqttChange>),
}

/// The password dialog.
pub(super) struct Ask {
    pub(super) purpose: Purpose,
    pub(super) module: Located,
    pub(super) password: Zeroizing<String>,
    pub(super) focus: bool,
    /// The text field's id: its own for each dialog, and its state (an undo history holding
    /// the password) dropped when the dialog closes.
    pub(super) field: egui::Id,
}

/// The MQTT tab's fields, as typed.
#[derive(Default)]
pub(super) struct MqttForm {
    /// The module's web console, `HOST[:PORT]` (empty: the module's address, port 80).
    pub(super) console: String,
    /// The settings last read or stored (what the fields started from).
    pub(super) loaded: Option<MqttSettings>,
    pub(super) on: bool,
    pub(super) broker: String,
    pub(super) host: String,
    pub(super) port: String,
    pub(super) client_id: String,
    pub(super) tls: bool,
    pub(super) prefix: String,
    pub(super) period_ms: String,
    pub(super) qos1: bool,
    pub(super) deadbands: String,
    pub(super) on_change: bool,
    pub(super) commands: bool,
    pub(super) sntp: String,
    pub(super) ca_file: String,
    pub(super) user: String,
    pub(super) password: Zeroizing<String>,
}

impl MqttForm {
    /// The fields from `s`, as read or stored.
    pub(super) fn load(&mut self, s: MqttSettings) {
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
        self.sntp = s.sntp.clone();
        self.loaded = Some(s);
    }

    /// The settings the fields say, or which field is not a number.
    pub(super) fn settings(&self) -> Result<MqttSettings, &'static str> {
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
            sntp: self.sntp.trim().to_owned(),
            ca: false,
            credentials: false,
        })
    }

    /// The web console's address: the field, or the module's address on port 80.
    pub(super) fn console(&self, m: &Located) -> Result<SocketAddr, String> {
        let given = self.console.trim();
        let text = if given.is_empty() { m.modbus.ip().to_string() } else { given.to_owned() };
        remodaq_client::modbus::resolve_on(&text, 80).map_err(|e| e.to_string())
    }
}
