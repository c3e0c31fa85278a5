//! The Trends tab: the series picked, pause, span and CSV export, and the trend points taken from
//! each reading.

use eframe::egui::{self, Ui};

use super::{field, tr, Utility, SPANS};
use crate::trend::Trend;
use crate::worker::Reading;

impl Utility {
    pub(super) fn trends_tab(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        ui.horizontal_wrapped(|ui| {
            let names: Vec<String> = self.trend.series.keys().cloned().collect();
            for name in names {
                let mut on = self.picked.contains(&name);
                if ui.checkbox(&mut on, &name).changed() {
                    if on {
                        self.picked.insert(name);
                    } else {
                        self.picked.remove(&name);
                    }
                }
            }
        });
        ui.horizontal(|ui| {
            let label = if self.paused.is_some() { tr(lang, "Resume") } else { tr(lang, "Pause") };
            if ui.button(label).clicked() {
                self.paused = if self.paused.is_some() { None } else { Some(self.now_s()) };
                self.freeze = self.paused.is_some();
            }
            let span = &mut self.span_s;
            ui.label(tr(lang, "Span"));
            egui::ComboBox::from_id_salt("trend-span")
                .selected_text(format!("{} min", *span / 60.0))
                .show_ui(ui, |ui| {
                    for s in SPANS {
                        ui.selectable_value(span, s, format!("{} min", s / 60.0));
                    }
                })
                .response
                .widget_info(|| egui::WidgetInfo::labeled(egui::Role::ComboBox, true, "Span"));
            field(ui, tr(lang, "CSV file"), &mut self.csv_path, None, 260.0);
            if ui.button(tr(lang, "Export CSV")).clicked() {
                self.export_csv();
            }
        });
        let until = self.paused.unwrap_or_else(|| self.now_s());
        let from = until - self.span_s;
        let live = self.paused.is_none();
        let picked: Vec<String> = self.picked.iter().cloned().collect();
        let plot =
            egui_plot::Plot::new("trend").legend(egui_plot::Legend::default()).x_axis_label(tr(lang, "time (s)"));
        let freeze = &mut self.freeze;
        let shown = plot.show(ui, |p| {
            if std::mem::take(freeze) {
                p.set_auto_bounds(false);
            }
            if live {
                // Running, the trend follows the last span with the values' range; paused, the
                // user zooms and drags freely (a double click fits it all again).
                p.set_auto_bounds(egui::Vec2b::new(false, true));
                p.set_plot_bounds_x(from..=until);
            }
            for name in &picked {
                if let Some(s) = self.trend.series.get(name) {
                    // Running, the points in view; paused, all up to the pause.
                    let first = if live { s.partition_point(|q| q[0] < from) } else { 0 };
                    let points: Vec<[f64; 2]> = s.range(first..).copied().filter(|q| q[0] <= until).collect();
                    p.line(egui_plot::Line::new(name.clone(), egui_plot::PlotPoints::new(points)));
                }
            }
        });
        let bounds = shown.transform.bounds();
        self.shown_span = Some((bounds.min()[0], bounds.max()[0].min(until)));
    }

    /// Writes what the plot shows (the picked series, all when none is picked, over the time
    /// span in view, up to the pause) to the CSV file.
    pub fn export_csv(&mut self) {
        let names: Vec<String> = if self.picked.is_empty() {
            self.trend.series.keys().cloned().collect()
        } else {
            self.picked.iter().cloned().collect()
        };
        let csv = self.trend.csv(&names, self.shown_span);
        match std::fs::write(&self.csv_path, csv) {
            Ok(()) => self.say(format!("{} {}", tr(self.lang, "Trend written to"), self.csv_path), false),
            Err(e) => self.say(format!("{} {}: {e}", tr(self.lang, "Cannot write"), self.csv_path), true),
        }
    }

    /// Picks a trend series by name.
    pub fn pick(&mut self, name: &str) {
        self.picked.insert(name.to_string());
    }
}

/// The trend points of a reading: channel values (8318), counters and frequencies (8350).
pub(super) fn record(trend: &mut Trend, module: &str, t: f64, r: &Reading) {
    match r {
        Reading::Analog(a) => {
            for c in &a.channels {
                if let Some(v) = c.value {
                    trend.push(&format!("{module} CH{} ({})", c.channel, a.unit), t, v);
                }
            }
            if let Some(c) = a.cold_junction_c {
                trend.push(&format!("{module} CJC (°C)"), t, c);
            }
        }
        Reading::Digital(d) => {
            for i in &d.inputs {
                let what = if i.mode == "frequency" { "Hz" } else { "count" };
                trend.push(&format!("{module} DI{} ({what})", i.channel), t, f64::from(i.value));
            }
        }
    }
}
