//! The RemoDAQ-8350 panel: DI modes, counters and latches, DO levels and pulses, and the host
//! watchdog.

use eframe::egui::{self, Color32, RichText, Ui};
use remodaq_client::settings::{CounterAction, Write};
use remodaq_protocol::m8350::{self, DiMode};

use super::{field, tr, AfterWrite, Utility};
use crate::worker::{Located, Reading};

fn di_mode_name(m: DiMode) -> &'static str {
    match m {
        DiMode::Normal => "Normal",
        DiMode::Counter => "Counter",
        DiMode::LatchRising => "Latch L-H",
        DiMode::LatchFalling => "Latch H-L",
        DiMode::Frequency => "Frequency",
    }
}

fn di_mode_of(name: &str) -> DiMode {
    match name {
        "counter" => DiMode::Counter,
        "latch-rising" => DiMode::LatchRising,
        "latch-falling" => DiMode::LatchFalling,
        "frequency" => DiMode::Frequency,
        _ => DiMode::Normal,
    }
}

impl Utility {
    pub(super) fn panel_8350(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        let Some(Reading::Digital(d)) = self.reading(m).cloned() else {
            ui.label(tr(lang, "Reading…"));
            return;
        };
        ui.heading("DI");
        ui.horizontal(|ui| {
            let l = ui.label(tr(lang, "Set all channels to"));
            egui::ComboBox::from_id_salt("all-mode")
                .selected_text(tr(lang, di_mode_name(self.all_mode)))
                .show_ui(ui, |ui| {
                    for mode in DiMode::ALL {
                        ui.selectable_value(&mut self.all_mode, mode, tr(lang, di_mode_name(mode)));
                    }
                })
                .response
                .labelled_by(l.id);
            if ui.button(tr(lang, "Set all")).clicked() {
                self.write(Write::DiModeAll(self.all_mode));
            }
        });
        let mac = m.mac;
        let latched = self.latched.get(&mac).copied().unwrap_or_default();
        let overflowed = self.overflowed.get(&mac).copied().unwrap_or_default();
        egui::Grid::new("di").num_columns(6).striped(true).show(ui, |ui| {
            for h in ["DI", "Mode", "Counter / frequency", "", "Latch", ""] {
                ui.label(tr(lang, h));
            }
            ui.end_row();
            for i in d.inputs.iter().filter(|i| i.channel < m8350::DI_CHANNELS) {
                let n = i.channel;
                let lamp = if i.state { Color32::from_rgb(0x20, 0xc0, 0x40) } else { Color32::DARK_GRAY };
                ui.label(RichText::new(format!("● DI{n} {}", if i.state { "ON" } else { "OFF" })).color(lamp));
                let mut mode = di_mode_of(i.mode);
                let was = mode;
                egui::ComboBox::from_id_salt(("di-mode", n))
                    .selected_text(tr(lang, di_mode_name(mode)))
                    .show_ui(ui, |ui| {
                        for choice in DiMode::ALL {
                            ui.selectable_value(&mut mode, choice, tr(lang, di_mode_name(choice)));
                        }
                    })
                    .response
                    .widget_info(|| egui::WidgetInfo::labeled(egui::Role::ComboBox, true, format!("DI{n} mode")));
                if mode != was {
                    self.write(Write::DiMode(n as u16, mode));
                }
                let value = match mode {
                    DiMode::Frequency => format!("DI{n} {} Hz", i.value),
                    _ => format!("DI{n} {}{}", i.value, if overflowed[n] { " (overflow)" } else { "" }),
                };
                ui.label(value);
                ui.horizontal(|ui| {
                    if ui.button(format!("Start DI{n}")).clicked() {
                        self.write(Write::Counter(n as u16, CounterAction::Start));
                    }
                    if ui.button(format!("Stop DI{n}")).clicked() {
                        self.write(Write::Counter(n as u16, CounterAction::Stop));
                    }
                    if ui.button(format!("Clear counter DI{n}")).clicked() {
                        let then = Some(AfterWrite::CounterCleared(mac, n));
                        self.write_then(Write::Counter(n as u16, CounterAction::Clear), then);
                    }
                    ui.label(if i.counter_running { tr(lang, "running") } else { tr(lang, "stopped") });
                });
                let latch = match (latched[n], mode) {
                    (true, DiMode::LatchFalling) => "H-L ON",
                    (true, _) => "L-H ON",
                    (false, _) => "—",
                };
                ui.label(format!("DI{n} latch {latch}"));
                // Shown until the module has taken the clear (a refused write keeps it).
                if ui.button(format!("Clear latch DI{n}")).clicked() {
                    self.write_then(Write::LatchClear(n as u16), Some(AfterWrite::LatchCleared(mac, n)));
                }
                ui.end_row();
            }
        });
        ui.separator();
        ui.heading("DO");
        egui::Grid::new("do").num_columns(8).striped(true).show(ui, |ui| {
            for h in ["DO", "Mode", "Low (ms)", "High (ms)", "Count", "Extra", "", ""] {
                ui.label(tr(lang, h));
            }
            ui.end_row();
            for o in &d.outputs {
                let n = o.channel;
                let mut on = o.state;
                if ui.toggle_value(&mut on, format!("DO{n} {}", if o.state { "ON" } else { "OFF" })).clicked() {
                    self.write(Write::Do(n as u16, on));
                }
                let mut pulse = o.mode == "pulse";
                if ui.checkbox(&mut pulse, format!("DO{n} pulse")).changed() {
                    self.write(Write::DoPulseMode(n as u16, pulse));
                }
                let form = &mut self.pulse_form[n];
                if form.iter().all(String::is_empty) {
                    *form = [format!("{}", o.low_ms), format!("{}", o.high_ms), o.count.to_string(), "0".into()];
                }
                for (k, what) in ["low", "high", "count", "extra"].iter().enumerate() {
                    let r = ui.add(
                        egui::TextEdit::singleline(&mut form[k]).desired_width(60.0).min_size(egui::vec2(60.0, 0.0)),
                    );
                    r.widget_info(|| egui::WidgetInfo::labeled(egui::Role::TextInput, true, format!("DO{n} {what}")));
                }
                let parsed = pulse_values(form);
                ui.horizontal(|ui| {
                    if ui.button(format!("Read DO{n}")).clicked() {
                        self.pulse_form[n] =
                            [format!("{}", o.low_ms), format!("{}", o.high_ms), o.count.to_string(), "0".into()];
                    }
                    if ui.button(format!("Write DO{n}")).clicked() {
                        match parsed {
                            Some((low, high, count, extra)) => {
                                self.write(Write::Pulse { channel: n as u16, low, high, count });
                                if extra > 0 {
                                    self.write(Write::Extra(n as u16, extra));
                                }
                            }
                            None => {
                                self.say(tr(lang, "Pulse widths are 0.1 ms or more; counts are whole numbers"), true)
                            }
                        }
                    }
                });
                ui.end_row();
            }
        });
        ui.separator();
        ui.heading(tr(lang, "Host watchdog"));
        let w = &d.watchdog;
        ui.label(format!(
            "{}: {} · {}: {:06b} · {}: {:06b}{}",
            tr(lang, "Timeout"),
            if w.timeout_s == 0.0 { tr(lang, "off").to_string() } else { format!("{} s", w.timeout_s) },
            tr(lang, "Safe levels"),
            w.safe,
            tr(lang, "Power-on levels"),
            w.power_on,
            if w.tripped { format!(" · {}", tr(lang, "TRIPPED: outputs held at safe levels")) } else { String::new() }
        ));
        ui.horizontal(|ui| {
            field(ui, tr(lang, "Watchdog timeout (s, 0 = off)"), &mut self.watchdog_form, None, 60.0);
            if ui.button(tr(lang, "Set watchdog")).clicked() {
                match self.watchdog_form.trim().parse::<f64>() {
                    Ok(s) if (s == 0.0 || (0.1..=600.0).contains(&s)) => self.write(Write::Watchdog {
                        tenths: (s * 10.0).round() as u32,
                        writes_only: w.writes_only,
                        auto_clear: w.auto_clear,
                    }),
                    _ => self.say(tr(lang, "The watchdog timeout is 0.1 to 600 s, or 0 for off"), true),
                }
            }
            if ui.button(tr(lang, "Clear trip")).clicked() {
                self.write(Write::WatchdogClear);
            }
        });
        ui.horizontal(|ui| {
            ui.label(tr(lang, "Safe levels"));
            for n in 0..m8350::DO_CHANNELS {
                let mut on = w.safe & 1 << n != 0;
                if ui.checkbox(&mut on, format!("safe DO{n}")).changed() {
                    self.write(Write::SafeLevels(w.safe ^ 1 << n));
                }
            }
        });
        ui.horizontal(|ui| {
            ui.label(tr(lang, "Power-on levels"));
            for n in 0..m8350::DO_CHANNELS {
                let mut on = w.power_on & 1 << n != 0;
                if ui.checkbox(&mut on, format!("power-on DO{n}")).changed() {
                    self.write(Write::PowerOnLevels(w.power_on ^ 1 << n));
                }
            }
        });
    }
}

/// Low and high widths (0.1 ms), count and extra pulses of a DO's form.
fn pulse_values(form: &[String; 4]) -> Option<(u32, u32, u32, u32)> {
    let ticks = |s: &str| {
        let t = (s.trim().parse::<f64>().ok()? * 10.0).round();
        (1.0..=f64::from(u32::MAX)).contains(&t).then_some(t as u32)
    };
    Some((ticks(&form[0])?, ticks(&form[1])?, form[2].trim().parse().ok()?, form[3].trim().parse().ok()?))
}
