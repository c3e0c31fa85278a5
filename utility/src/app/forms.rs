//! What the window keeps of its forms between frames: the Network Settings tab's fields as
//! typed, and the password dialog with what the password is asked for.

use std::path::PathBuf;

use eframe::egui;
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
