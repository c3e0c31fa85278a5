//! The window: menu, toolbar, the tree of modules by the PC's interfaces, and a module's tabs
//! (manuals, chapter 3). Everything it shows comes from the worker's events; nothing here
//! waits on the network.

use std::collections::{BTreeSet, HashMap};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use eframe::egui::{self, Color32, RichText, Ui};
use remodaq_client::ifaces::Iface;
use remodaq_client::lan::Mac;
use remodaq_client::reading::{type_name, Diagnostics};
use remodaq_client::settings::{CounterAction, Write};
use remodaq_client::update::Progress;
use remodaq_client::Error;
use remodaq_protocol::access::AllowList;
use remodaq_protocol::m8318::{self, InputType, INPUT_TYPES};
use remodaq_protocol::m8350::{self, DiMode};

use crate::i18n::Lang;
use crate::trend::Trend;
use crate::validate::{self, Problem};
use crate::worker::{Clock, Config, Done, Event, Job, Located, Reading, Worker};
use zeroize::Zeroizing;

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
    Firmware,
}

/// What a password is asked for.
#[derive(Clone, Debug)]
enum Purpose {
    SetNetwork(remodaq_client::lan::NetChange),
    Restart,
    SetPassword(Zeroizing<String>),
    GetAccess,
    SetAccess(AllowList),
    Update(PathBuf),
}

/// The password dialog.
struct Ask {
    purpose: Purpose,
    module: Located,
    password: Zeroizing<String>,
    focus: bool,
    /// The text field's id: its own for each dialog, and its state (an undo history holding
    /// the password) dropped when the dialog closes.
    field: egui::Id,
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

/// The fields of the Network Settings tab, as typed.
#[derive(Default)]
struct NetForm {
    ip: String,
    mask: String,
    gateway: String,
    port: String,
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

/// Frames not counted in the statistics after the warm-up (they build the font atlas and lay
/// out every view once).
pub const WARM_UP: u64 = 10;

/// The frames drawn, the longest UI pass (all the app does in a frame), and after the first
/// [`WARM_UP`] frames the longest UI pass and the whole frames as the window's integration
/// measures them (the UI, tessellation and painting, without the wait for the screen).
#[derive(Default)]
pub struct FrameStats {
    pub frames: u64,
    pub longest_ui: Duration,
    pub longest_ui_warm: Duration,
    /// Whole frames measured after the warm-up, the longest (s), those over 16 ms (a 60 Hz
    /// screen's frame) and their sum (s).
    whole: u64,
    longest_whole: f32,
    slow_whole: u64,
    whole_sum: f64,
}

impl FrameStats {
    /// One UI pass that took `took`.
    fn ui_pass(&mut self, took: Duration) {
        self.frames += 1;
        self.longest_ui = self.longest_ui.max(took);
        if self.frames > WARM_UP {
            self.longest_ui_warm = self.longest_ui_warm.max(took);
        }
    }

    /// The previous whole frame's time, s.
    fn whole_frame(&mut self, s: f32) {
        if self.frames > WARM_UP {
            self.whole += 1;
            self.longest_whole = self.longest_whole.max(s);
            self.slow_whole += u64::from(s > 0.016);
            self.whole_sum += f64::from(s);
        }
    }

    /// The line `scripts/utility-report` reads.
    fn line(&self) -> String {
        format!(
            "frames {} longest_ui_ms {:.3} longest_after_warm_up_ms {:.3} longest_frame_after_warm_up_ms {:.3} slower_than_16ms {} mean_frame_ms {:.3}\n",
            self.frames,
            self.longest_ui.as_secs_f64() * 1e3,
            self.longest_ui_warm.as_secs_f64() * 1e3,
            self.longest_whole * 1e3,
            self.slow_whole,
            self.whole_sum * 1e3 / self.whole.max(1) as f64
        )
    }
}

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

    fn menu(&mut self, ui: &mut Ui) {
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

    fn toolbar(&mut self, ui: &mut Ui) {
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

    /// The modules under `Host (address)`, one node per interface of the PC they answered on.
    fn tree(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        let mut groups: Vec<(String, Vec<Located>)> = Vec::new();
        for m in &self.modules {
            let host = match &m.iface {
                Some(i) => format!("Host ({})", i.ip),
                None => format!(
                    "Host ({})",
                    if m.to.ip().is_loopback() { "127.0.0.1".into() } else { m.to.ip().to_string() }
                ),
            };
            match groups.iter_mut().find(|(h, _)| *h == host) {
                Some((_, list)) => list.push(m.clone()),
                None => groups.push((host, vec![m.clone()])),
            }
        }
        if groups.is_empty() {
            let host = self.interfaces.first().map_or("Host".to_string(), |i| format!("Host ({})", i.ip));
            if ui.selectable_label(self.host_selected, host).clicked() {
                self.select(None);
            }
            ui.label(if self.searched_once { tr(lang, "No module answered") } else { tr(lang, "Press Search") });
        }
        let mut clicked = None;
        for (host, list) in groups {
            egui::CollapsingHeader::new(host).default_open(true).show(ui, |ui| {
                for m in list {
                    let state = self.seen.get(&m.mac);
                    let silent =
                        state.is_some_and(|s| matches!(s.error, Some(Error::Timeout(_)) | Some(Error::Other(_))));
                    let mut text = module_label(&m);
                    if silent {
                        text.push_str(&format!(" — {}", tr(lang, "no answer")));
                    }
                    if ui.selectable_label(self.selected == Some(m.mac), text).clicked() {
                        clicked = Some(m.mac);
                    }
                }
            });
        }
        if let Some(mac) = clicked {
            self.select(Some(mac));
        }
    }

    fn host_info(&mut self, ui: &mut Ui) {
        let lang = self.lang;
        ui.heading(tr(lang, "Host Information"));
        egui::Grid::new("host").num_columns(2).show(ui, |ui| {
            for i in &self.interfaces {
                ui.label(tr(lang, "IP address"));
                ui.label(i.label());
                ui.end_row();
            }
            ui.label(tr(lang, "Recent host IPs"));
            ui.label(self.recent_hosts.join(", "));
            ui.end_row();
            ui.label(tr(lang, "Modules found"));
            ui.label(self.modules.len().to_string());
            ui.end_row();
        });
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
            Tab::Firmware => self.firmware_tab(ui, &m),
        });
    }

    fn problem(&self, p: Option<Problem>) -> Option<&'static str> {
        p.map(|p| tr(self.lang, crate::i18n::problem(p)))
    }

    fn network_tab(&mut self, ui: &mut Ui, m: &Located) {
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

    fn ask(&mut self, purpose: Purpose, m: &Located) {
        let field = egui::Id::unique(("password", self.next_id));
        self.next_id += 1;
        self.ask = Some(Ask { purpose, module: m.clone(), password: Zeroizing::default(), focus: true, field });
    }

    fn password_dialog(&mut self, ctx: &egui::Context) {
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
                self.worker.send(Job::Update { id, modbus: module.modbus, image, password });
                return;
            }
            Purpose::SetNetwork(change) => Config::SetNetwork(change),
            Purpose::Restart => Config::Restart,
            Purpose::SetPassword(new) => Config::SetPassword(new),
            Purpose::GetAccess => Config::GetAccess,
            Purpose::SetAccess(list) => Config::SetAccess(list),
        };
        if matches!(command, Config::Restart) {
            self.say(tr(self.lang, "Restarting; searching again…"), false);
        }
        let id = self.id("config");
        self.worker.send(Job::Config { id, module: Box::new(module), password, command, search_at, only });
    }

    fn reading(&self, m: &Located) -> Option<&Reading> {
        self.seen.get(&m.mac).and_then(|s| s.reading.as_ref())
    }

    fn panel_8318(&mut self, ui: &mut Ui, m: &Located) {
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

    fn panel_8350(&mut self, ui: &mut Ui, m: &Located) {
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

    fn trends_tab(&mut self, ui: &mut Ui) {
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

    fn diagnostics_tab(&mut self, ui: &mut Ui, m: &Located) {
        let lang = self.lang;
        let diag: Option<Diagnostics> = match self.reading(m) {
            Some(Reading::Analog(a)) => Some(a.diagnostics.clone()),
            Some(Reading::Digital(d)) => Some(d.diagnostics.clone()),
            None => None,
        };
        let Some(d) = diag else {
            ui.label(tr(lang, "Reading…"));
            return;
        };
        egui::Grid::new("diag").num_columns(2).striped(true).show(ui, |ui| {
            let status = if d.status.is_empty() { "ok".to_string() } else { d.status.join(", ") };
            let e = &d.security;
            let rows: [(&str, String); 11] = [
                ("Module status", format!("{status} ({:04X}h)", d.status_raw)),
                ("Uptime", format!("{} s", d.uptime_s)),
                ("Reset cause", d.reset_cause.to_string()),
                ("Connections", d.connections.to_string()),
                ("Requests", d.requests.to_string()),
                ("Exceptions", d.exceptions.to_string()),
                ("Failed authentications", e.auth_failures.to_string()),
                ("Last failed source", e.last_failed_source.map_or("—".into(), |ip| ip.to_string())),
                ("Refused by the guessing budget", e.budget_refusals.to_string()),
                ("Writes refused by the allow-list", e.access_refusals.to_string()),
                ("Updates refused", e.update_refusals.to_string()),
            ];
            for (k, v) in rows {
                ui.label(tr(lang, k));
                ui.label(format!("{}: {v}", tr(lang, k)));
                ui.end_row();
            }
        });
    }

    fn security_tab(&mut self, ui: &mut Ui, m: &Located) {
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

    fn firmware_tab(&mut self, ui: &mut Ui, m: &Located) {
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

/// A module as the tree and the trend name it: `RemoDAQ-8318 (190.5.200.110)` as in the
/// manuals, with the Modbus port for a module on this PC (simulated ones share an address).
pub fn module_label(m: &Located) -> String {
    if m.modbus.ip().is_loopback() {
        format!("{} ({}:{})", m.found.name, m.modbus.ip(), m.modbus.port())
    } else {
        format!("{} ({})", m.found.name, m.found.running.ip)
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

/// Low and high widths (0.1 ms), count and extra pulses of a DO's form.
fn pulse_values(form: &[String; 4]) -> Option<(u32, u32, u32, u32)> {
    let ticks = |s: &str| {
        let t = (s.trim().parse::<f64>().ok()? * 10.0).round();
        (1.0..=f64::from(u32::MAX)).contains(&t).then_some(t as u32)
    };
    Some((ticks(&form[0])?, ticks(&form[1])?, form[2].trim().parse().ok()?, form[3].trim().parse().ok()?))
}

/// The trend points of a reading: channel values (8318), counters and frequencies (8350).
fn record(trend: &mut Trend, module: &str, t: f64, r: &Reading) {
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
