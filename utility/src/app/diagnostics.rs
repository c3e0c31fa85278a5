//! The Diagnostics tab: the module's status, counters and security events.

use eframe::egui::{self, Ui};
use remodaq_client::reading::Diagnostics;

use super::{tr, Utility};
use crate::worker::{Located, Reading};

impl Utility {
    pub(super) fn diagnostics_tab(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        let diag: Option<Diagnostics> = match self.reading(m) {
            Some(Reading::Analog(a)) => Some(a.diagnostics.clone()),
            Some(Reading::Digital(d)) => Some(d.diagnostics.clone()),
            None => None,
        };
        let Some(d) = diag else {
            ui.label(tr(lang, "Reading…"));
            return;
        };
        egui::Grid::new("diag").num_columns(2).striped(true).show(ui, |ui| {
            let status = if d.status.is_empty() { "ok".to_string() } else { d.status.join(", ") };
            let e = &d.security;
            let rows: [(&str, String); 11] = [
                ("Module status", format!("{status} ({:04X}h)", d.status_raw)),
                ("Uptime", format!("{} s", d.uptime_s)),
                ("Reset cause", d.reset_cause.to_string()),
                ("Connections", d.connections.to_string()),
                ("Requests", d.requests.to_string()),
                ("Exceptions", d.exceptions.to_string()),
                ("Failed authentications", e.auth_failures.to_string()),
                ("Last failed source", e.last_failed_source.map_or("—".into(), |ip| ip.to_string())),
                ("Refused by the guessing budget", e.budget_refusals.to_string()),
                ("Writes refused by the allow-list", e.access_refusals.to_string()),
                ("Updates refused", e.update_refusals.to_string()),
            ];
            for (k, v) in rows {
                ui.label(tr(lang, k));
                ui.label(format!("{}: {v}", tr(lang, k)));
                ui.end_row();
            }
        });
    }
}
