//! The RemoDAQ-8318 panel: input range, channels, cold-junction compensation and open inputs.

use eframe::egui::{self, Color32, RichText, Ui};
use remodaq_client::reading::type_name;
use remodaq_client::settings::Write;
use remodaq_protocol::m8318::{InputType, INPUT_TYPES};

use super::{field, tr, Utility};
use crate::worker::{Located, Reading};

impl Utility {
    pub(super) fn panel_8318(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        let Some(Reading::Analog(a)) = self.reading(m).cloned() else {
            ui.label(tr(lang, "Reading…"));
            return;
        };
        let current = u16::from_str_radix(&a.type_code, 16).unwrap_or(0);
        let mut choice = *self.type_choice.get_or_insert(current);
        let name = |code: u16| {
            InputType::from_code(code as u8)
                .map_or(format!("{code:02X}"), |t| format!("{code:02X} {}", type_name(&t).0))
        };
        ui.horizontal(|ui| {
            let l = ui.label(tr(lang, "Input range"));
            egui::ComboBox::from_id_salt("input-type")
                .selected_text(name(choice))
                .width(240.0)
                .show_ui(ui, |ui| {
                    for t in INPUT_TYPES {
                        ui.selectable_value(&mut choice, u16::from(t.code), name(u16::from(t.code)));
                    }
                })
                .response
                .labelled_by(l.id);
            self.type_choice = Some(choice);
            if ui.button(tr(lang, "Setting")).clicked() {
                self.write(Write::InputType(choice));
            }
        });
        let mut enable: u16 = a.channels.iter().filter(|c| c.enabled).fold(0, |m, c| m | 1 << c.channel);
        egui::Grid::new("channels").num_columns(4).striped(true).show(ui, |ui| {
            ui.label(tr(lang, "Channel"));
            ui.label(tr(lang, "Value"));
            ui.label(tr(lang, "Status"));
            ui.label("");
            ui.end_row();
            for c in &a.channels {
                let mut on = c.enabled;
                if ui.checkbox(&mut on, format!("CH{}", c.channel)).changed() {
                    enable ^= 1 << c.channel;
                    self.write(Write::Enable(enable));
                }
                let value = c.value.map_or("—".to_string(), |v| format!("{v:.3} {}", a.unit));
                ui.label(format!("CH{} {value}", c.channel));
                let colour = match c.status {
                    "ok" => ui.visuals().text_color(),
                    "disabled" => Color32::GRAY,
                    "open" => Color32::from_rgb(0xd0, 0x80, 0x00),
                    _ => Color32::from_rgb(0xd0, 0x30, 0x30),
                };
                ui.label(RichText::new(format!("CH{} {}", c.channel, tr(lang, status_word(c.status)))).color(colour));
                ui.label(format!("{:04X}h", c.raw));
                ui.end_row();
            }
        });
        ui.separator();
        ui.label(match a.cold_junction_c {
            Some(t) => format!("{}: {t:.2} °C", tr(lang, "CJC temperature")),
            None => format!("{}: —", tr(lang, "CJC temperature")),
        });
        ui.horizontal(|ui| {
            if self.cjc_offset.is_empty() {
                self.cjc_offset = format!("{:.2}", a.cjc_offset_c);
            }
            field(ui, tr(lang, "CJC offset (°C)"), &mut self.cjc_offset, None, 80.0);
            if ui.button(tr(lang, "Set offset")).clicked() {
                match self.cjc_offset.trim().parse::<f64>() {
                    Ok(c) if c.is_finite() && c.abs() <= 50.0 => {
                        self.write(Write::CjcOffset((c * 100.0).round() as i32))
                    }
                    _ => self.say(tr(lang, "The CJC offset is -50.00 to 50.00 °C"), true),
                }
            }
        });
        ui.horizontal(|ui| {
            ui.label(tr(lang, "Open input reads"));
            let down = a.open_value == "downscale";
            if ui.radio(!down, tr(lang, "FFFFh (upscale)")).clicked() && down {
                self.write(Write::OpenDownscale(false));
            }
            if ui.radio(down, tr(lang, "0000h (downscale)")).clicked() && !down {
                self.write(Write::OpenDownscale(true));
            }
        });
    }
}

fn status_word(s: &str) -> &'static str {
    match s {
        "ok" => "ok",
        "open" => "open",
        "over range" => "over range",
        "under range" => "under range",
        "disabled" => "disabled",
        "front-end fault" => "front-end fault",
        "cold-junction fault" => "cold-junction fault",
        _ => "unknown",
    }
}
