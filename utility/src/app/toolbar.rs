//! The menu bar and the toolbar (search, interface, language).

use eframe::egui::{self, Ui};
use remodaq_client::ifaces::Iface;

use super::{tr, Utility};
use crate::i18n::Lang;

/// The toolbar's search button: a magnifying glass (drawn: the fonts have no such glyph) and
/// `text`; `label` is what assistive technologies (and the tests) know it by.
fn search_button(ui: &mut Ui, text: &str, label: &str) -> egui::Response {
    let galley = ui.painter().layout_no_wrap(
        text.to_string(),
        egui::TextStyle::Button.resolve(ui.style()),
        ui.visuals().text_color(),
    );
    let pad = ui.spacing().button_padding;
    let icon = 14.0;
    let size = egui::vec2(pad.x * 2.0 + icon + 4.0 + galley.size().x, (pad.y * 2.0 + galley.size().y).max(icon + 4.0));
    let (rect, response) = ui.allocate_exact_size(size, egui::Sense::click());
    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Button, true, label));
    if ui.is_rect_visible(rect) {
        let visuals = ui.style().interact(&response);
        ui.painter().rect(
            rect,
            visuals.corner_radius,
            visuals.weak_bg_fill,
            visuals.bg_stroke,
            egui::StrokeKind::Inside,
        );
        let stroke = egui::Stroke::new(1.6, visuals.fg_stroke.color);
        let c = egui::pos2(rect.left() + pad.x + 5.5, rect.center().y - 1.5);
        ui.painter().circle_stroke(c, 4.5, stroke);
        ui.painter().line_segment([c + egui::vec2(3.2, 3.2), c + egui::vec2(7.0, 7.0)], stroke);
        let at = egui::pos2(rect.left() + pad.x + icon + 4.0, rect.center().y - galley.size().y / 2.0);
        ui.painter().galley(at, galley, visuals.text_color());
    }
    response
}

impl Utility {
    pub(super) fn menu(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        egui::MenuBar::new().ui(ui, |ui| {
            ui.menu_button(tr(lang, "File"), |ui| {
                if ui.button(tr(lang, "Export trend to CSV")).clicked() {
                    self.export_csv();
                }
                if ui.button(tr(lang, "Exit")).clicked() {
                    ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
                }
            });
            ui.menu_button(tr(lang, "Tool"), |ui| {
                if ui.button(tr(lang, "Search")).clicked() {
                    self.search();
                }
                ui.separator();
                ui.label(tr(lang, "Language"));
                if ui.radio(self.lang == Lang::En, "English").clicked() {
                    self.lang = Lang::En;
                }
                if ui.radio(self.lang == Lang::Zh, "简体中文").clicked() {
                    self.lang = Lang::Zh;
                }
            });
            ui.menu_button(tr(lang, "Help"), |ui| {
                ui.label(format!("RemoDAQ-8300 Utility {}", env!("CARGO_PKG_VERSION")));
                ui.label(tr(lang, "Modules: RemoDAQ-8318, RemoDAQ-8350"));
            });
        });
    }

    pub(super) fn toolbar(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        ui.horizontal(|ui| {
            if search_button(
                ui,
                tr(lang, if self.searching { "Searching…" } else { "Search" }),
                tr(lang, "Search the LAN"),
            )
            .on_hover_text(tr(lang, "Search the LAN for modules"))
            .clicked()
            {
                self.search();
            }
            ui.separator();
            let l = ui.label(tr(lang, "Interface"));
            let all = tr(lang, "All interfaces").to_string();
            let current = self
                .only
                .as_ref()
                .and_then(|n| self.interfaces.iter().find(|i| &i.name == n))
                .map_or(all.clone(), Iface::label);
            egui::ComboBox::from_id_salt("interface")
                .selected_text(current)
                .show_ui(ui, |ui| {
                    ui.selectable_value(&mut self.only, None, all);
                    for i in &self.interfaces {
                        ui.selectable_value(&mut self.only, Some(i.name.clone()), i.label());
                    }
                })
                .response
                .labelled_by(l.id);
            ui.separator();
            ui.label(tr(lang, "Language"));
            ui.selectable_value(&mut self.lang, Lang::En, "English");
            ui.selectable_value(&mut self.lang, Lang::Zh, "中文");
        });
    }
}
