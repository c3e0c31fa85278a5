//! The Firmware tab: the version, the update key and an update from an image file.

use std::path::PathBuf;

use eframe::egui::{self, Ui};

use super::password::Purpose;
use super::{field, tr, Utility};
use crate::worker::Located;

impl Utility {
    pub(super) fn firmware_tab(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        ui.label(format!("{}: {}", tr(lang, "Firmware version"), m.found.firmware));
        ui.label(format!("{}: {}", tr(lang, "Update key"), m.found.update_key));
        field(ui, tr(lang, "Image file"), &mut self.image_path, None, 360.0);
        let busy = self.progress.is_some();
        if ui.add_enabled(!busy && !self.image_path.trim().is_empty(), egui::Button::new(tr(lang, "Update"))).clicked()
        {
            let path = PathBuf::from(self.image_path.trim());
            match remodaq_client::update::read_image(&path) {
                Ok((_, h)) if format!("{:04X}", h.model) != m.found.model => {
                    self.say(format!("{} {:04X}", tr(lang, "The image is for a"), h.model), true)
                }
                Ok(_) => self.ask(Purpose::Update(path), m),
                Err(e) => self.say(e.to_string(), true),
            }
        }
        if let Some((sent, total, verifying)) = self.progress {
            let f = if total == 0 { 0.0 } else { sent as f32 / total as f32 };
            let text = if verifying {
                tr(lang, "verifying, then restarting…").to_string()
            } else {
                format!("{sent} / {total} B")
            };
            ui.add(egui::ProgressBar::new(f).text(text));
        }
    }
}
