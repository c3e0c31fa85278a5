//! The Network Settings tab.

use eframe::egui::{self, Color32, RichText, Ui};

use super::forms::{NetForm, Purpose};
use super::{field, tr, Utility};
use crate::validate::{self, Problem};
use crate::worker::Located;

impl Utility {
    fn problem(&self, p: Option<Problem>) -> Option<&'static str> {
        p.map(|p| tr(self.lang, crate::i18n::problem(p)))
    }

    pub(super) fn network_tab(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        let (checked, change) = validate::check(&self.net.ip, &self.net.mask, &self.net.gateway, &self.net.port);
        let problems = [
            self.problem(checked.ip),
            self.problem(checked.mask),
            self.problem(checked.gateway),
            self.problem(checked.port),
        ];
        egui::Grid::new("net").num_columns(3).show(ui, |ui| {
            let NetForm { ip, mask, gateway, port, .. } = &mut self.net;
            for ((label, text), problem) in [
                (tr(lang, "IP address"), ip),
                (tr(lang, "Subnet mask"), mask),
                (tr(lang, "Gateway"), gateway),
                (tr(lang, "Remote port"), port),
            ]
            .into_iter()
            .zip(problems)
            {
                field(ui, label, text, problem, 160.0);
                ui.end_row();
            }
        });
        ui.horizontal(|ui| {
            let setting = ui.add_enabled(change.is_some(), egui::Button::new(tr(lang, "Setting")));
            if setting.clicked() {
                if let Some(change) = change {
                    self.ask(Purpose::SetNetwork(change), m);
                }
            }
            if ui.button(tr(lang, "ReStart")).clicked() {
                self.ask(Purpose::Restart, m);
            }
            if ui.button(tr(lang, "Search")).clicked() {
                self.search();
            }
        });
        ui.separator();
        let (r, s) = (m.found.running, m.found.stored);
        let gw = |g: std::net::Ipv4Addr| if g.is_unspecified() { tr(lang, "none").to_string() } else { g.to_string() };
        ui.label(format!(
            "{}: {} / {}, {} {}, {} {}",
            tr(lang, "In force"),
            r.ip,
            r.mask,
            tr(lang, "gateway"),
            gw(r.gateway),
            tr(lang, "port"),
            r.port
        ));
        if s != r {
            ui.label(format!(
                "{}: {} / {}, {} {}, {} {}",
                tr(lang, "Stored (after a restart)"),
                s.ip,
                s.mask,
                tr(lang, "gateway"),
                gw(s.gateway),
                tr(lang, "port"),
                s.port
            ));
        }
        ui.label(format!(
            "MAC {} · {} {} · {} {} s",
            m.mac,
            tr(lang, "firmware"),
            m.found.firmware,
            tr(lang, "up"),
            m.found.uptime_s
        ));
        if m.found.factory_password {
            ui.label(
                RichText::new(tr(lang, "The factory password is in force: anyone on the LAN can change these settings. Set one in Security."))
                    .color(Color32::from_rgb(0xc0, 0x80, 0x00)),
            );
        }
    }
}
