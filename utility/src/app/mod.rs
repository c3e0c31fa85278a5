//! The window: menu, toolbar, the tree of modules by the PC's interfaces, and a module's tabs
//! (manuals, chapter 3). Everything it shows comes from the worker's events; nothing here
//! waits on the network.
//!
//! This file holds the utility's state, the frame (its panels and the tab switch) and the
//! helpers the tabs share; each tab, the menu and toolbar, the tree and the password dialog
//! are in a file of their own.

use std::collections::{BTreeSet, HashMap};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use eframe::egui::{self, Color32, RichText, Ui};
use remodaq_client::ifaces::Iface;
use remodaq_client::lan::Mac;
use remodaq_client::settings::Write;
use remodaq_client::Error;
use remodaq_protocol::m8318;
use remodaq_protocol::m8350::{self, DiMode};

use crate::i18n::Lang;
use crate::trend::Trend;
use crate::worker::{Clock, Job, Located, Reading, Worker};
use zeroize::Zeroizing;

mod diagnostics;
mod events;
mod firmware;
mod forms;
mod mqtt;
mod network;
mod panel_8318;
mod panel_8350;
mod password;
mod security;
mod stats;
mod toolbar;
mod tree;
mod trends;

use forms::{Ask, NetForm};
pub use stats::{FrameStats, WARM_UP};

/// How the utility is started.
#[derive(Clone, Debug)]
pub struct Options {
    /// Where a search goes: the broadcast address (every interface), or modules' own discovery
    /// addresses.
    pub search_at: Vec<SocketAddr>,
    /// How long a module may take to answer.
    pub timeout: Duration,
    /// How often the selected module is read (its 10 Hz).
    pub fast_poll: Duration,
    /// How often the others are read, for their state in the tree.
    pub slow_poll: Duration,
    /// Search once at start.
    pub search_at_start: bool,
    /// The module to open once a search finds it (its Modbus address).
    pub select: Option<SocketAddr>,
    /// Where to write, at most once a second, the frames drawn and the longest UI pass
    /// (`REMODAQ_UTILITY_STATS`, for the responsiveness report).
    pub stats: Option<PathBuf>,
    /// The clock of the readings and the trend's time axis (the system's; tests hold it).
    pub clock: Clock,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            search_at: vec![SocketAddr::from(([255, 255, 255, 255], remodaq_protocol::discovery::PORT))],
            timeout: Duration::from_secs(1),
            fast_poll: Duration::from_millis(100),
            slow_poll: Duration::from_secs(1),
            search_at_start: true,
            stats: None,
            select: None,
            clock: Clock::default(),
        }
    }
}

/// The tabs of a module.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tab {
    Network,
    Panel,
    Trends,
    Diagnostics,
    Security,
    Mqtt,
    Firmware,
}

/// What a successful write changes in what the window shows.
#[derive(Clone, Copy, Debug)]
enum AfterWrite {
    LatchCleared(Mac, usize),
    CounterCleared(Mac, usize),
}

/// Forgets a text field's state: its undo history would otherwise keep a password typed in it.
fn forget_text(ctx: &egui::Context, id: egui::Id) {
    egui::text_edit::TextEditState::default().store(ctx, id);
}

/// The latest of a module.
#[derive(Default)]
struct Seen {
    reading: Option<Reading>,
    /// The last poll failed with this.
    error: Option<Error>,
}

/// A message of the status line.
struct Message {
    text: String,
    error: bool,
}

/// The utility's state.
pub struct Utility {
    worker: Worker,
    pub options: Options,
    pub lang: Lang,
    interfaces: Vec<Iface>,
    /// The interface to search on (its name); `None`: all.
    only: Option<String>,
    modules: Vec<Located>,
    searching: bool,
    searched_once: bool,
    recent_hosts: Vec<String>,
    selected: Option<Mac>,
    host_selected: bool,
    pub tab: Tab,
    seen: HashMap<Mac, Seen>,
    net: NetForm,
    ask: Option<Ask>,
    pending: HashMap<u64, String>,
    next_id: u64,
    message: Option<Message>,
    /// The module whose forms are filled in (a new search keeps them).
    shown_module: Option<Mac>,
    // 8318 panel.
    type_choice: Option<u16>,
    cjc_offset: String,
    // 8350 panel.
    all_mode: DiMode,
    /// Per 8350, the latches and counter overflows seen set (reading them clears them in the
    /// module): shown until Clear.
    latched: HashMap<Mac, [bool; m8350::DI_CHANNELS]>,
    overflowed: HashMap<Mac, [bool; m8350::DI_CHANNELS]>,
    /// What to do when a write succeeds (by job id).
    after_write: HashMap<u64, AfterWrite>,
    /// The time span the trend plot showed last (what Export CSV writes).
    shown_span: Option<(f64, f64)>,
    pulse_form: [[String; 4]; m8350::DO_CHANNELS],
    watchdog_form: String,
    // Security tab.
    new_password: Zeroizing<String>,
    new_password_again: Zeroizing<String>,
    allow_text: String,
    mqtt: forms::MqttForm,
    // Firmware tab.
    image_path: String,
    progress: Option<(u64, u64, bool)>,
    // Trends.
    pub trend: Trend,
    picked: BTreeSet<String>,
    paused: Option<f64>,
    /// The span of time the trend shows while it runs, s ([`SPANS`]).
    span_s: f64,
    /// Set by Pause: the plot keeps the view it had (until the user zooms, drags or fits).
    freeze: bool,
    started: Instant,
    csv_path: String,
    /// Frame statistics for the responsiveness report.
    pub stats: FrameStats,
    stats_written: Option<Instant>,
}

/// The spans of time the running trend can show, s (the last minute to the ten minutes it keeps).
pub const SPANS: [f64; 4] = [60.0, 120.0, 300.0, crate::trend::KEEP_S];

fn tr(lang: Lang, en: &'static str) -> &'static str {
    lang.t(en)
}

/// A short word for an error class (the CLI's exit classes).
pub fn class(e: &Error) -> &'static str {
    match e {
        Error::Timeout(_) => "no answer",
        Error::Exception(_) => "Modbus exception",
        Error::Refused(_) => "refused",
        Error::Reply(_) => "bad reply",
        Error::Other(_) => "error",
    }
}

/// A text field with a visible label that is also its AccessKit label.
fn field(ui: &mut Ui, label: &str, text: &mut String, problem: Option<&str>, width: f32) -> egui::Response {
    let l = ui.label(label);
    let r = ui
        .add(egui::TextEdit::singleline(text).desired_width(width).min_size(egui::vec2(width, 0.0)))
        .labelled_by(l.id);
    if let Some(p) = problem {
        ui.label(RichText::new(p).color(Color32::from_rgb(0xd0, 0x30, 0x30)));
    }
    r
}

impl Utility {
    /// A utility whose worker wakes `ctx` when something arrives.
    pub fn new(ctx: &egui::Context, options: Options) -> std::io::Result<Self> {
        let wake = ctx.clone();
        let worker = Worker::start(move || wake.request_repaint(), options.timeout, options.clock.clone())?;
        let started = options.clock.now();
        let mut u = Self {
            worker,
            options,
            lang: Lang::En,
            interfaces: remodaq_client::ifaces::list(None).unwrap_or_default(),
            only: None,
            modules: Vec::new(),
            searching: false,
            searched_once: false,
            recent_hosts: Vec::new(),
            selected: None,
            host_selected: true,
            tab: Tab::Network,
            seen: HashMap::new(),
            net: NetForm::default(),
            ask: None,
            pending: HashMap::new(),
            next_id: 1,
            message: None,
            shown_module: None,
            type_choice: None,
            cjc_offset: String::new(),
            all_mode: DiMode::Normal,
            latched: HashMap::new(),
            overflowed: HashMap::new(),
            after_write: HashMap::new(),
            shown_span: None,
            pulse_form: Default::default(),
            watchdog_form: String::new(),
            new_password: Zeroizing::default(),
            new_password_again: Zeroizing::default(),
            allow_text: String::new(),
            mqtt: forms::MqttForm::default(),
            image_path: String::new(),
            progress: None,
            trend: Trend::default(),
            picked: BTreeSet::new(),
            paused: None,
            span_s: SPANS[0],
            freeze: false,
            started,
            csv_path: std::env::temp_dir().join("remodaq-trend.csv").to_string_lossy().into_owned(),
            stats: FrameStats::default(),
            stats_written: None,
        };
        u.remember_hosts();
        if u.options.search_at_start {
            u.search();
        }
        Ok(u)
    }

    fn remember_hosts(&mut self) {
        for i in &self.interfaces {
            let ip = i.ip.to_string();
            if !self.recent_hosts.contains(&ip) {
                self.recent_hosts.push(ip);
            }
        }
        let n = self.recent_hosts.len();
        if n > 8 {
            self.recent_hosts.drain(..n - 8);
        }
    }

    /// Starts a search.
    pub fn search(&mut self) {
        self.searching = true;
        self.interfaces = remodaq_client::ifaces::list(None).unwrap_or_default();
        self.remember_hosts();
        self.worker.send(Job::Search { at: self.options.search_at.clone(), only: self.only.clone() });
    }

    fn id(&mut self, what: impl Into<String>) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        self.pending.insert(id, what.into());
        id
    }

    fn say(&mut self, text: impl Into<String>, error: bool) {
        self.message = Some(Message { text: text.into(), error });
    }

    fn selected_module(&self) -> Option<&Located> {
        self.selected.and_then(|mac| self.modules.iter().find(|m| m.mac == mac))
    }

    /// Selects a module by MAC (or none).
    pub fn select(&mut self, mac: Option<Mac>) {
        self.selected = mac;
        self.host_selected = mac.is_none();
        if self.net.port.is_empty() || mac != self.shown_module {
            self.type_choice = None;
            self.pulse_form = Default::default();
            self.cjc_offset.clear();
        }
        self.shown_module = mac;
        if let Some(m) = self.selected_module().cloned() {
            let s = m.found.stored;
            let gateway = if s.gateway.is_unspecified() { String::new() } else { s.gateway.to_string() };
            self.net = NetForm { ip: s.ip.to_string(), mask: s.mask.to_string(), gateway, port: s.port.to_string() };
        }
        self.repoll();
    }

    /// Polls the selected module fast and the others slowly.
    fn repoll(&mut self) {
        let list = self
            .modules
            .iter()
            .map(|m| {
                let shown = Some(m.mac) == self.selected;
                (m.clone(), if shown { self.options.fast_poll } else { self.options.slow_poll }, shown)
            })
            .collect();
        self.worker.send(Job::Poll(list));
    }

    fn write(&mut self, write: Write) {
        self.write_then(write, None);
    }

    /// Queues a write to the module shown; `then` changes what is shown once it succeeded.
    fn write_then(&mut self, write: Write, then: Option<AfterWrite>) {
        let Some(m) = self.selected_module() else { return };
        let modbus = m.modbus;
        let id = self.id(format!("{write:?}"));
        if let Some(then) = then {
            self.after_write.insert(id, then);
        }
        self.worker.send(Job::Write { id, modbus, write });
    }

    /// Seconds since the utility started: the time axis of the trend.
    pub fn now_s(&self) -> f64 {
        self.options.clock.now().saturating_duration_since(self.started).as_secs_f64()
    }

    /// Draws the whole window (one frame).
    pub fn show(&mut self, ui: &mut Ui) {
        let began = Instant::now();
        self.take_events();
        let ctx = ui.ctx().clone();
        egui::Panel::top("menu").show(ui, |ui| self.menu(ui));
        egui::Panel::top("toolbar").show(ui, |ui| self.toolbar(ui));
        egui::Panel::bottom("status").show(ui, |ui| {
            match &self.message {
                Some(m) if m.error => ui.label(RichText::new(&m.text).color(Color32::from_rgb(0xd0, 0x30, 0x30))),
                Some(m) => ui.label(&m.text),
                None => ui.label(tr(self.lang, "Ready")),
            };
        });
        egui::Panel::left("tree").resizable(true).default_size(250.0).min_size(230.0).show(ui, |ui| {
            egui::ScrollArea::vertical().show(ui, |ui| self.tree(ui));
        });
        egui::CentralPanel::default_margins().show(ui, |ui| {
            if self.selected_module().is_some() {
                self.module_view(ui);
            } else {
                self.host_info(ui);
            }
        });
        self.password_dialog(&ctx);
        self.stats.ui_pass(began.elapsed());
        if let Some(path) = &self.options.stats {
            if self.stats_written.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
                self.stats_written = Some(Instant::now());
                let line = self.stats.line();
                // A report's aid: a failure to write it changes nothing in the window.
                let _ = std::fs::write(path, line);
            }
        }
    }

    fn module_view(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        let Some(m) = self.selected_module().cloned() else { return };
        ui.horizontal(|ui| {
            ui.heading(format!("{} — {}", m.found.name, m.mac));
            if let Some(e) = self.seen.get(&m.mac).and_then(|s| s.error.as_ref()) {
                ui.label(
                    RichText::new(format!("{}: {e}", tr(lang, class(e)))).color(Color32::from_rgb(0xd0, 0x30, 0x30)),
                );
            }
        });
        ui.horizontal(|ui| {
            let panel = if m.found.model == "8318" { "RemoDAQ-8318" } else { "RemoDAQ-8350" };
            for (tab, name) in [
                (Tab::Network, tr(lang, "Network Settings")),
                (Tab::Panel, panel),
                (Tab::Trends, tr(lang, "Trends")),
                (Tab::Diagnostics, tr(lang, "Diagnostics")),
                (Tab::Security, tr(lang, "Security")),
                (Tab::Mqtt, "MQTT"),
                (Tab::Firmware, tr(lang, "Firmware")),
            ] {
                ui.selectable_value(&mut self.tab, tab, name);
            }
        });
        ui.separator();
        egui::ScrollArea::vertical().show(ui, |ui| match self.tab {
            Tab::Network => self.network_tab(ui, &m),
            Tab::Panel if m.found.model == "8318" => self.panel_8318(ui, &m),
            Tab::Panel => self.panel_8350(ui, &m),
            Tab::Trends => self.trends_tab(ui),
            Tab::Diagnostics => self.diagnostics_tab(ui, &m),
            Tab::Security => self.security_tab(ui, &m),
            Tab::Mqtt => self.mqtt_tab(ui, &m),
            Tab::Firmware => self.firmware_tab(ui, &m),
        });
    }

    fn reading(&self, m: &Located) -> Option<&Reading> {
        self.seen.get(&m.mac).and_then(|s| s.reading.as_ref())
    }
}

/// A module as the tree and the trend name it: `RemoDAQ-8318 (190.5.200.110)` as in the
/// manuals, with the Modbus port for a module on this PC (simulated ones share an address).
pub fn module_label(m: &Located) -> String {
    if m.modbus.ip().is_loopback() {
        format!("{} ({}:{})", m.found.name, m.modbus.ip(), m.modbus.port())
    } else {
        format!("{} ({})", m.found.name, m.found.running.ip)
    }
}

/// The model of a reading (analog: 8318, digital: 8350).
pub fn model_of(r: &Reading) -> u16 {
    match r {
        Reading::Analog(_) => m8318::MODULE_NAME,
        Reading::Digital(_) => m8350::MODULE_NAME,
    }
}

impl Utility {
    /// The latest reading of a module (tests compare it with their own Modbus reads).
    pub fn latest(&self, mac: Mac) -> Option<&Reading> {
        self.seen.get(&mac).and_then(|s| s.reading.as_ref())
    }

    /// The modules of the last search.
    pub fn modules(&self) -> &[Located] {
        &self.modules
    }

    /// The status line's text.
    pub fn message(&self) -> Option<&str> {
        self.message.as_ref().map(|m| m.text.as_str())
    }
}

impl eframe::App for Utility {
    fn ui(&mut self, ui: &mut Ui, frame: &mut eframe::Frame) {
        // The previous frame's whole time (eframe measures it; none on the first frame).
        if let Some(s) = frame.info().cpu_usage {
            self.stats.whole_frame(s);
        }
        self.show(ui);
    }
}
