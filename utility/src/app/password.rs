//! The configuration password dialog, and the commands it sends once the password is given.

use eframe::egui;
use zeroize::Zeroizing;

use super::forms::Ask;
pub(super) use super::forms::Purpose;
use super::{forget_text, tr, Utility};
use crate::worker::{Config, Job, Located};

impl Utility {
    pub(super) fn ask(&mut self, purpose: Purpose, m: &Located) {
        let field = egui::Id::unique(("password", self.next_id));
        self.next_id += 1;
        self.ask = Some(Ask { purpose, module: m.clone(), password: Zeroizing::default(), focus: true, field });
    }

    pub(super) fn password_dialog(&mut self, ctx: &egui::Context) {
        let lang = self.lang;
        let Some(ask) = self.ask.as_mut() else { return };
        let mut ok = false;
        let mut cancel = false;
        egui::Modal::new(egui::Id::unique("password")).show(ctx, |ui| {
            ui.heading(tr(lang, "Configuration password"));
            ui.label(format!("{} ({})", ask.module.found.name, ask.module.mac));
            let l = ui.label(tr(lang, "Password"));
            let r = ui
                .add(egui::TextEdit::singleline(&mut *ask.password).id(ask.field).password(true).desired_width(220.0))
                .labelled_by(l.id);
            if ask.focus {
                r.request_focus();
                ask.focus = false;
            }
            if r.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter)) {
                ok = true;
            }
            ui.horizontal(|ui| {
                ok |= ui.button(tr(lang, "OK")).clicked();
                cancel = ui.button(tr(lang, "Cancel")).clicked() || ui.input(|i| i.key_pressed(egui::Key::Escape));
            });
        });
        if cancel || ok {
            if let Some(ask) = self.ask.take() {
                forget_text(ctx, ask.field);
                if ok {
                    self.submit(ask);
                }
            }
        }
    }

    fn submit(&mut self, ask: Ask) {
        let Ask { purpose, module, password, .. } = ask;
        let search_at = self.options.search_at.clone();
        let only = self.only.clone();
        let command = match purpose {
            Purpose::Update(image) => {
                let id = self.id("update");
                self.progress = Some((0, 1, false));
                self.worker.send(Job::Update { id, modbus: module.modbus, mac: module.mac, image, password });
                return;
            }
            Purpose::SetNetwork(change) => Config::SetNetwork(change),
            Purpose::Restart => Config::Restart,
            Purpose::SetPassword(new) => Config::SetPassword(new),
            Purpose::GetAccess => Config::GetAccess,
            Purpose::SetAccess(list) => Config::SetAccess(list),
            Purpose::GetMqtt(web) => Config::GetMqtt(web),
            Purpose::SetMqtt(change) => Config::SetMqtt(change),
        };
        if matches!(command, Config::Restart) {
            self.say(tr(self.lang, "Restarting; searching again…"), false);
        }
        let id = self.id("config");
        self.worker.send(Job::Config { id, module: Box::new(module), password, command, search_at, only });
    }
}
