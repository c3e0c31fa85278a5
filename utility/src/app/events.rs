//! What the window does with the worker's events: search results, readings, update progress
//! and the outcome of writes and configuration commands.

use remodaq_client::update::Progress;
use remodaq_protocol::m8350;

use super::trends::record;
use super::{class, module_label, tr, AfterWrite, Tab, Utility};
use crate::worker::{Done, Event, Reading};

impl Utility {
    /// Takes the worker's events.
    pub fn take_events(&mut self) {
        for event in self.worker.ready() {
            match event {
                Event::Searched(Ok((found, interfaces))) => {
                    self.searching = false;
                    self.searched_once = true;
                    if !interfaces.is_empty() {
                        self.interfaces = interfaces;
                    }
                    self.remember_hosts();
                    self.modules = found;
                    self.modules.sort_by_key(|m| (m.found.running.ip, m.found.running.port));
                    let n = self.modules.len();
                    self.say(format!("{}: {n}", tr(self.lang, "Modules found")), false);
                    let wanted = self.options.select.take_if(|_| self.selected.is_none());
                    if let Some(m) = wanted.and_then(|at| self.modules.iter().find(|m| m.modbus == at)) {
                        let mac = m.mac;
                        self.tab = Tab::Panel;
                        self.select(Some(mac));
                    } else if self.selected.is_some_and(|mac| !self.modules.iter().any(|m| m.mac == mac)) {
                        self.select(None);
                    } else {
                        self.select(self.selected);
                    }
                }
                Event::Searched(Err(e)) => {
                    self.searching = false;
                    self.say(format!("{}: {e}", tr(self.lang, "The search failed")), true);
                }
                Event::Reading { mac, at, reading } => {
                    let t = at.saturating_duration_since(self.started).as_secs_f64();
                    let name = self.modules.iter().find(|m| m.mac == mac).map(module_label);
                    let seen = self.seen.entry(mac).or_default();
                    match *reading {
                        Ok(r) => {
                            if let Reading::Digital(d) = &r {
                                let latched = self.latched.entry(mac).or_default();
                                let overflowed = self.overflowed.entry(mac).or_default();
                                for i in d.inputs.iter().filter(|i| i.channel < m8350::DI_CHANNELS) {
                                    latched[i.channel] |= i.latch;
                                    overflowed[i.channel] |= i.overflow;
                                }
                            }
                            if let Some(name) = name {
                                record(&mut self.trend, &name, t, &r);
                            }
                            seen.reading = Some(r);
                            seen.error = None;
                        }
                        Err(e) => seen.error = Some(e),
                    }
                }
                Event::Progress { progress, .. } => {
                    self.progress = Some(match progress {
                        Progress::Sent(a, b) => (a, b, false),
                        Progress::Verifying | Progress::Restarting(..) => {
                            let total = self.progress.map_or(1, |p| p.1);
                            (total, total, true)
                        }
                    });
                }
                Event::Done { id, result } => {
                    let what = self.pending.remove(&id).unwrap_or_default();
                    match (self.after_write.remove(&id), &result) {
                        (Some(AfterWrite::LatchCleared(mac, n)), Ok(_)) => {
                            if let Some(l) = self.latched.get_mut(&mac).and_then(|l| l.get_mut(n)) {
                                *l = false;
                            }
                        }
                        (Some(AfterWrite::CounterCleared(mac, n)), Ok(_)) => {
                            if let Some(o) = self.overflowed.get_mut(&mac).and_then(|o| o.get_mut(n)) {
                                *o = false;
                            }
                        }
                        _ => {}
                    }
                    match result {
                        Ok(Done::Said(s)) => self.say(s, false),
                        Ok(Done::Access(list)) => {
                            let nets: Vec<String> = list.iter().map(remodaq_client::lan::cidr).collect();
                            self.allow_text = nets.join(", ");
                            let text = if nets.is_empty() {
                                tr(self.lang, "Modbus writes allowed from any client").to_string()
                            } else {
                                format!("{}: {}", tr(self.lang, "Modbus writes allowed only from"), nets.join(", "))
                            };
                            self.say(text, false);
                        }
                        Ok(Done::Restarted(Some(back))) => {
                            let mac = back.mac;
                            let r = back.found.running;
                            if let Some(m) = self.modules.iter_mut().find(|m| m.mac == mac) {
                                *m = *back;
                            } else {
                                self.modules.push(*back);
                            }
                            self.select(Some(mac));
                            self.say(
                                format!(
                                    "{}: {} / {}, {} {}, {} {}",
                                    tr(self.lang, "Restarted; in force"),
                                    r.ip,
                                    r.mask,
                                    tr(self.lang, "gateway"),
                                    r.gateway,
                                    tr(self.lang, "port"),
                                    r.port
                                ),
                                false,
                            );
                        }
                        Ok(Done::Mqtt(settings)) => {
                            self.mqtt.load(*settings);
                            self.say(tr(self.lang, "MQTT settings as the module holds them"), false);
                        }
                        Ok(Done::Restarted(None)) => {
                            self.say(tr(self.lang, "The module did not answer a search after its restart"), true)
                        }
                        Ok(Done::Updated { before, after }) => {
                            self.progress = None;
                            self.say(format!("{} {before:04X} → {after:04X}", tr(self.lang, "Firmware")), false);
                        }
                        Err(e) => {
                            if what == "update" {
                                self.progress = None;
                            }
                            self.say(format!("{}: {e}", tr(self.lang, class(&e))), true);
                        }
                    }
                }
            }
        }
    }
}
