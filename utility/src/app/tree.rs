//! The tree of modules by the PC's interfaces, and the host's information shown when no module
//! is selected.

use eframe::egui::{self, Ui};
use remodaq_client::Error;

use super::{module_label, tr, Utility};
use crate::worker::Located;

impl Utility {
    /// The modules under `Host (address)`, one node per interface of the PC they answered on.
    pub(super) fn tree(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        let mut groups: Vec<(String, Vec<Located>)> = Vec::new();
        for m in &self.modules {
            let host = match &m.iface {
                Some(i) => format!("Host ({})", i.ip),
                None => format!(
                    "Host ({})",
                    if m.to.ip().is_loopback() { "127.0.0.1".into() } else { m.to.ip().to_string() }
                ),
            };
            match groups.iter_mut().find(|(h, _)| *h == host) {
                Some((_, list)) => list.push(m.clone()),
                None => groups.push((host, vec![m.clone()])),
            }
        }
        if groups.is_empty() {
            let host = self.interfaces.first().map_or("Host".to_string(), |i| format!("Host ({})", i.ip));
            if ui.selectable_label(self.host_selected, host).clicked() {
                self.select(None);
            }
            ui.label(if self.searched_once { tr(lang, "No module answered") } else { tr(lang, "Press Search") });
        }
        let mut clicked = None;
        for (host, list) in groups {
            egui::CollapsingHeader::new(host).default_open(true).show(ui, |ui| {
                for m in list {
                    let state = self.seen.get(&m.mac);
                    let silent =
                        state.is_some_and(|s| matches!(s.error, Some(Error::Timeout(_)) | Some(Error::Other(_))));
                    let mut text = module_label(&m);
                    if silent {
                        text.push_str(&format!(" — {}", tr(lang, "no answer")));
                    }
                    if ui.selectable_label(self.selected == Some(m.mac), text).clicked() {
                        clicked = Some(m.mac);
                    }
                }
            });
        }
        if let Some(mac) = clicked {
            self.select(Some(mac));
        }
    }

    pub(super) fn host_info(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        ui.heading(tr(lang, "Host Information"));
        egui::Grid::new("host").num_columns(2).show(ui, |ui| {
            for i in &self.interfaces {
                ui.label(tr(lang, "IP address"));
                ui.label(i.label());
                ui.end_row();
            }
            ui.label(tr(lang, "Recent host IPs"));
            ui.label(self.recent_hosts.join(", "));
            ui.end_row();
            ui.label(tr(lang, "Modules found"));
            ui.label(self.modules.len().to_string());
            ui.end_row();
        });
    }
}
