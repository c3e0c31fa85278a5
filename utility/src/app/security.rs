//! The Security tab: the configuration password and the Modbus write allow-list.

use eframe::egui::{self, Ui};
use remodaq_protocol::access::AllowList;
use zeroize::Zeroizing;

use super::password::Purpose;
use super::{field, forget_text, tr, Utility};
use crate::worker::Located;

impl Utility {
    pub(super) fn security_tab(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        ui.heading(tr(lang, "Password"));
        let l = ui.label(tr(lang, "New password"));
        let (new_id, again_id) = (egui::Id::unique("new-password"), egui::Id::unique("new-password-again"));
        ui.add(egui::TextEdit::singleline(&mut *self.new_password).id(new_id).password(true)).labelled_by(l.id);
        let l = ui.label(tr(lang, "New password again"));
        ui.add(egui::TextEdit::singleline(&mut *self.new_password_again).id(again_id).password(true)).labelled_by(l.id);
        let long_enough = self.new_password.chars().count() >= remodaq_protocol::auth::MIN_PASSWORD_LEN;
        let same = self.new_password == self.new_password_again;
        if !self.new_password.is_empty() && !long_enough {
            ui.label(tr(lang, "At least 8 characters"));
        } else if !same {
            ui.label(tr(lang, "The two new passwords differ"));
        }
        if ui.add_enabled(long_enough && same, egui::Button::new(tr(lang, "Change password"))).clicked() {
            let new = std::mem::take(&mut self.new_password);
            self.new_password_again = Zeroizing::default();
            forget_text(ui.ctx(), new_id);
            forget_text(ui.ctx(), again_id);
            self.ask(Purpose::SetPassword(new), m);
        }
        ui.separator();
        ui.heading(tr(lang, "Modbus write allow-list"));
        ui.label(tr(lang, "Up to 4 networks (192.168.0.0/24, 10.0.0.5); empty: any client may write"));
        field(ui, tr(lang, "Allowed networks"), &mut self.allow_text, None, 320.0);
        ui.horizontal(|ui| {
            if ui.button(tr(lang, "Read list")).clicked() {
                self.ask(Purpose::GetAccess, m);
            }
            if ui.button(tr(lang, "Store list")).clicked() {
                let nets: Result<Vec<_>, String> = self
                    .allow_text
                    .split([',', ' '])
                    .filter(|s| !s.trim().is_empty())
                    .map(|s| remodaq_client::lan::parse_cidr(s.trim()))
                    .collect();
                match nets.map(|n| AllowList::of(&n)) {
                    Ok(Some(list)) => self.ask(Purpose::SetAccess(list), m),
                    Ok(None) => self.say(tr(lang, "At most 4 networks"), true),
                    Err(e) => self.say(e, true),
                }
            }
        });
    }
}
