//! What the GUI scenarios and snapshots share: simulated modules, the utility in an
//! egui_kittest harness, and the tests' own Modbus and discovery reads.

#![allow(dead_code, unused_imports)]

use std::net::{SocketAddr, TcpListener, UdpSocket};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

pub use remodaq_protocol::auth::FACTORY_PASSWORD;
pub use remodaq_protocol::identity::REG_NAME;
pub use remodaq_protocol::{diag, m8318, m8350};

use eframe::egui;
use egui_kittest::kittest::{NodeT, Queryable};
use egui_kittest::Harness;
use remodaq_board_host::testing::{program, SimModule};
pub use remodaq_utility::worker::Clock;
use remodaq_utility::{Options, Utility};
pub use tokio_modbus::ExceptionCode;

/// How long the utility waits for a module in these tests.
pub const TIMEOUT: Duration = Duration::from_millis(500);

/// A program of the workspace (`firmware-8318`, `remodaq`), next to the test binaries' `deps`
/// directory (`cargo test --workspace` builds it).
fn workspace_program(name: &str) -> String {
    let exe = std::env::current_exe().expect("test binary");
    let beside = exe.parent().and_then(|d| d.parent()).expect("target dir").join(name);
    let path = program(name, &beside);
    assert!(path.exists(), "{} is missing: run the workspace's tests (cargo test --workspace)", path.display());
    path.to_string_lossy().into_owned()
}

/// A firmware's host build.
pub fn firmware(model: &str) -> String {
    workspace_program(&format!("firmware-{model}"))
}

/// The workspace's root directory.
pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the utility is in the workspace").to_path_buf()
}

/// Says that a test could not make its checks here, on the test process's standard error
/// itself (the harness keeps what a passing test prints with `eprintln!`).
pub fn not_applicable(what: &str, why: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{what}: not applicable: {why}");
}

/// Signs `firmware` (any bytes, at least 1 KiB and 16 bytes: a copy stamped with the identity of
/// `model` and `counter` that `remodaq sign` asks of an image) into the image file `out` for
/// `model` (`8318`, `8350`), `version` (hex) and security `counter`, with the test update key,
/// as a vendor does (`remodaq sign --key keys/test-update.key`, docs/update.md).
pub fn sign(firmware: &Path, model: &str, version: &str, counter: u32, out: &Path) {
    use remodaq_protocol::update::{Identity, IDENTITY_AT, IDENTITY_LEN};
    let mut bytes = std::fs::read(firmware).expect("the firmware");
    let identity = Identity { model: u16::from_str_radix(model, 16).expect("a model"), counter };
    bytes[IDENTITY_AT as usize..][..IDENTITY_LEN].copy_from_slice(&identity.encode());
    let firmware = &out.with_extension("bin");
    std::fs::write(firmware, bytes).expect("the stamped firmware");
    let key = workspace().join("keys/test-update.key");
    let result = std::process::Command::new(workspace_program("remodaq"))
        .args(["sign", "--key"])
        .arg(&key)
        .args(["--model", model, "--version", version, "--counter", &counter.to_string()])
        .arg(firmware)
        .arg("--out")
        .arg(out)
        .output()
        .expect("remodaq sign runs");
    assert!(result.status.success(), "remodaq sign: {}", String::from_utf8_lossy(&result.stderr));
}

pub fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("remodaq-utility-tests-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join(name);
    let _ = std::fs::remove_file(&path);
    path
}

pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).expect("a free port").port()
}

fn free_udp_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0").and_then(|s| s.local_addr()).expect("a free UDP port").port()
}

/// A scenario file of a simulated module (host-build.md), rewritten to change its inputs.
pub struct Scenario(PathBuf);

impl Scenario {
    pub fn new(name: &str, text: &str) -> Self {
        let s = Scenario(temp(&format!("{name}.toml")));
        s.write(text);
        s
    }

    pub fn path(&self) -> &str {
        self.0.to_str().expect("utf-8 path")
    }

    /// Writes the file whole (a rename, so the module never reads half of it).
    pub fn write(&self, text: &str) {
        let tmp = self.0.with_extension("tmp");
        std::fs::write(&tmp, text).expect("write scenario");
        std::fs::rename(&tmp, &self.0).expect("rename scenario");
    }
}

/// A simulated module on loopback, with a fixed discovery port (so that a restart keeps it).
pub struct Sim {
    module: SimModule,
}

impl Sim {
    /// A module on an ephemeral Modbus port.
    pub fn start(model: &str, test: &str, args: &[&str]) -> Self {
        let discovery = format!("127.0.0.1:{}", free_udp_port());
        let mut all = vec!["--listen", "127.0.0.1:0", "--discovery", &discovery];
        all.extend_from_slice(args);
        let flash = temp(&format!("{test}-{model}.flash"));
        Sim { module: SimModule::start_with(&firmware(model), &flash, &all) }
    }

    /// A module on fixed ports (snapshots show them: the pictures must not change with them).
    pub fn start_at(model: &str, test: &str, modbus: u16, discovery: u16, args: &[&str]) -> Self {
        let (listen, discovery) = (format!("127.0.0.1:{modbus}"), format!("127.0.0.1:{discovery}"));
        let mut all = vec!["--listen", &listen, "--discovery", &discovery];
        all.extend_from_slice(args);
        let flash = temp(&format!("{test}-{model}.flash"));
        Sim { module: SimModule::start_with(&firmware(model), &flash, &all) }
    }

    /// A module listening on the port of its settings (which a restart changes): first seeded
    /// with a free port (a run on an ephemeral port that stores it), then started on it.
    pub fn start_from_settings(model: &str, test: &str, scenario: &Scenario) -> Self {
        let flash = temp(&format!("{test}-{model}.flash"));
        let port = free_port();
        {
            let seed = SimModule::start(&firmware(model), &flash);
            let mac = discover(seed.discovery).mac;
            let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
            let change = remodaq_client::lan::NetChange {
                ip: [192, 168, 0, 1].into(),
                mask: [255, 255, 255, 0].into(),
                gateway: [0, 0, 0, 0].into(),
                port,
            };
            runtime
                .block_on(remodaq_client::lan::set_network(
                    seed.discovery,
                    None,
                    remodaq_client::lan::Mac(mac),
                    FACTORY_PASSWORD,
                    change,
                    Duration::from_secs(2),
                ))
                .expect("seed the port");
            seed.kill();
        }
        let discovery = format!("127.0.0.1:{}", free_udp_port());
        let args = ["--listen", "127.0.0.1", "--discovery", &discovery, "--scenario", scenario.path()];
        let sim = Sim { module: SimModule::start_with(&firmware(model), &flash, &args) };
        assert_eq!(sim.port(), port, "listening on the stored port");
        sim
    }

    pub fn addr(&self) -> SocketAddr {
        self.module.addr
    }

    pub fn port(&self) -> u16 {
        self.module.addr.port()
    }

    pub fn discovery(&self) -> SocketAddr {
        self.module.discovery
    }

    /// Its web console (started with `--http`).
    pub fn web(&self) -> Option<SocketAddr> {
        self.module.web
    }

    pub fn wait_restarted(&mut self) {
        self.module.wait_listening();
    }

    pub fn kill(self) {
        self.module.kill();
    }

    /// Stops the module (SIGSTOP: its sockets stay open and accept, nothing answers); `false`
    /// where it was killed instead (Windows).
    pub fn stop(&mut self) -> bool {
        self.module.stop()
    }

    /// Lets a stopped module run again (SIGCONT).
    pub fn resume(&mut self) {
        self.module.resume();
    }
}

/// What a module says of itself to a search (the test's own discovery request).
pub struct Info {
    pub mac: [u8; 6],
    pub model: u16,
    pub version: u16,
    pub running_port: u16,
    pub stored_port: u16,
    /// The factory password is in force (flag bit 1 of the answer, docs/discovery.md).
    pub factory_password: bool,
    /// The Modbus write allow-list is not empty (flag bit 0).
    pub writes_restricted: bool,
}

pub fn discover(at: SocketAddr) -> Info {
    discover_within(at, 10).unwrap_or_else(|| panic!("no answer to a search at {at}"))
}

/// A search at `at`, tried `attempts` times (500 ms each).
pub fn discover_within(at: SocketAddr, attempts: u16) -> Option<Info> {
    use remodaq_protocol::discovery::{decode_info, encode_request, Request, MAX_DATAGRAM};
    let socket = UdpSocket::bind("127.0.0.1:0").expect("udp");
    socket.set_read_timeout(Some(Duration::from_millis(500))).expect("timeout");
    let mut buf = [0u8; MAX_DATAGRAM];
    for attempt in 0..attempts {
        let id = 0x5100 + attempt;
        let n = encode_request(id, &Request::Search, &mut buf).expect("search request");
        socket.send_to(&buf[..n], at).expect("send");
        let mut rx = [0u8; 512];
        while let Ok((n, _)) = socket.recv_from(&mut rx) {
            if let Some(i) = decode_info(&rx[..n]).filter(|i| i.id == id) {
                return Some(Info {
                    mac: i.mac,
                    model: i.model,
                    version: i.version,
                    running_port: i.running.port,
                    stored_port: i.stored.port,
                    factory_password: i.flags & 0b10 != 0,
                    writes_restricted: i.flags & 0b01 != 0,
                });
            }
        }
    }
    None
}

fn modbus<T>(addr: SocketAddr, f: impl FnOnce(&mut tokio_modbus::client::sync::Context) -> T) -> T {
    let mut ctx = tokio_modbus::client::sync::tcp::connect_with_timeout(addr, Some(Duration::from_secs(2)))
        .expect("Modbus connection");
    f(&mut ctx)
}

/// Holding registers (function 03) at a PDU address.
pub fn holding(addr: SocketAddr, at: u16, n: u16) -> Vec<u16> {
    use tokio_modbus::client::sync::Reader;
    modbus(addr, |c| c.read_holding_registers(at, n).expect("transport").expect("no exception"))
}

/// Coils (function 01) at a PDU address.
pub fn coils(addr: SocketAddr, at: u16, n: u16) -> Vec<bool> {
    use tokio_modbus::client::sync::Reader;
    modbus(addr, |c| c.read_coils(at, n).expect("transport").expect("no exception"))
}

/// Writes holding registers (function 16) at a PDU address: the module's exception, if any.
pub fn write_registers(addr: SocketAddr, at: u16, values: &[u16]) -> Result<(), ExceptionCode> {
    use tokio_modbus::client::sync::Writer;
    modbus(addr, |c| c.write_multiple_registers(at, values).expect("transport"))
}

/// Writes a coil (function 05) at a PDU address: the module's exception, if any.
pub fn write_coil(addr: SocketAddr, at: u16, on: bool) -> Result<(), ExceptionCode> {
    use tokio_modbus::client::sync::Writer;
    modbus(addr, |c| c.write_single_coil(at, on).expect("transport"))
}

/// Discrete inputs (function 02) at a PDU address.
pub fn discrete(addr: SocketAddr, at: u16, n: u16) -> Vec<bool> {
    use tokio_modbus::client::sync::Reader;
    modbus(addr, |c| c.read_discrete_inputs(at, n).expect("transport").expect("no exception"))
}

/// The type K temperature of `mv` (cold junction at 0 °C), interpolated in the NIST ITS-90
/// table (1 °C steps) vendored with the 8318's tests.
pub fn nist_k_temperature(mv: f64) -> f64 {
    let points = nist_k_table();
    let i = points.windows(2).position(|w| w[0].1 <= mv && mv <= w[1].1).expect("mv within the table");
    let ((t0, e0), (t1, e1)) = (points[i], points[i + 1]);
    t0 + (mv - e0) / (e1 - e0) * (t1 - t0)
}

/// The type K emf of a junction at `t` °C against one at 0 °C, mV (the same table).
pub fn nist_k_emf(t: f64) -> f64 {
    let points = nist_k_table();
    let i = points.windows(2).position(|w| w[0].0 <= t && t <= w[1].0).expect("t within the table");
    let ((t0, e0), (t1, e1)) = (points[i], points[i + 1]);
    e0 + (t - t0) / (t1 - t0) * (e1 - e0)
}

/// The type K table from 0 °C up: (°C, mV).
fn nist_k_table() -> Vec<(f64, f64)> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../modules/8318/tests/reference/nist-its90-tables.tab");
    let text = std::fs::read_to_string(path).expect("the NIST tables");
    let mut points: Vec<(f64, f64)> = Vec::new();
    let mut in_k = false;
    for line in text.lines() {
        if line.contains("ITS-90 Table for type") {
            in_k = line.contains("type K ");
            continue;
        }
        if !in_k {
            continue;
        }
        let cells: Vec<&str> = line.split_whitespace().collect();
        let Some(Ok(t)) = cells.first().map(|c| c.parse::<i32>()) else { continue };
        if t < 0 || cells.len() < 2 {
            continue;
        }
        for (k, c) in cells[1..].iter().enumerate() {
            if let Ok(e) = c.parse::<f64>() {
                points.push((f64::from(t + k as i32), e));
            }
        }
    }
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    points.dedup_by(|a, b| a.0 == b.0);
    points
}

/// What a node says: its label, or for a text its value (egui's labels carry their text as
/// the value).
fn text(n: &egui_kittest::Node<'_>) -> Option<String> {
    let node = n.accesskit_node();
    node.label().or_else(|| node.value())
}

/// The utility in a harness.
pub struct Gui {
    pub harness: Harness<'static, Option<Utility>>,
}

impl Gui {
    pub fn new(search_at: Vec<SocketAddr>) -> Self {
        Self::sized(search_at, egui::vec2(1280.0, 900.0))
    }

    pub fn sized(search_at: Vec<SocketAddr>, size: egui::Vec2) -> Self {
        Self::with(search_at, size, TIMEOUT, Clock::default())
    }

    /// The utility waiting `timeout` for a module, its readings and trend timed by `clock`.
    pub fn with(search_at: Vec<SocketAddr>, size: egui::Vec2, timeout: Duration, clock: Clock) -> Self {
        let options = Options { search_at, timeout, search_at_start: false, clock, ..Options::default() };
        let harness = Harness::builder()
            .with_size(size)
            .with_context_setup(|ctx| {
                remodaq_utility::fonts::install(ctx);
            })
            .build_ui_state(
                move |ui, state: &mut Option<Utility>| {
                    if state.is_none() {
                        *state = Some(Utility::new(ui.ctx(), options.clone()).expect("the utility's worker"));
                    }
                    if let Some(app) = state.as_mut() {
                        app.show(ui);
                    }
                },
                None,
            );
        Gui { harness }
    }

    pub fn app(&self) -> &Utility {
        self.harness.state().as_ref().expect("started")
    }

    pub fn app_mut(&mut self) -> &mut Utility {
        self.harness.state_mut().as_mut().expect("started")
    }

    /// Runs `n` frames.
    pub fn frames(&mut self, n: usize) {
        for _ in 0..n {
            self.harness.step();
        }
    }

    /// Runs frames for `d` (20 ms apart).
    pub fn frames_for(&mut self, d: Duration) {
        let t = Instant::now();
        while t.elapsed() < d {
            self.harness.step();
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// A node whose label is exactly `label`.
    pub fn has(&self, label: &str) -> bool {
        self.harness.query_all_by_label(label).next().is_some()
    }

    /// A node whose label contains `part`.
    pub fn has_part(&self, part: &str) -> bool {
        self.harness.query_all_by_label_contains(part).next().is_some()
    }

    pub fn count_part(&self, part: &str) -> usize {
        self.harness.query_all_by_label_contains(part).count()
    }

    /// Runs frames until `ok` (at most 20 s), else fails saying `what` and what the utility
    /// last said.
    pub fn wait(&mut self, what: &str, ok: impl Fn(&Gui) -> bool) {
        self.wait_for(what, Duration::from_secs(20), ok);
    }

    /// [`wait`](Self::wait), at most `limit`.
    pub fn wait_for(&mut self, what: &str, limit: Duration, ok: impl Fn(&Gui) -> bool) {
        let t = Instant::now();
        loop {
            self.harness.step();
            if ok(self) {
                return;
            }
            if t.elapsed() > limit {
                let said = self.app().message().unwrap_or("nothing").to_string();
                let labels: Vec<String> =
                    self.harness.query_all_by_label_contains("").filter_map(|n| text(&n)).take(300).collect();
                panic!("waited {} s for {what}; the utility said: {said}; it shows: {labels:?}", limit.as_secs());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Clicks the widget labelled `label` (through AccessKit), then runs two frames.
    pub fn click(&mut self, label: &str) {
        let t = Instant::now();
        while self.harness.query_by_label(label).is_none() {
            assert!(t.elapsed() < Duration::from_secs(20), "no widget labelled {label:?}");
            self.harness.step();
            std::thread::sleep(Duration::from_millis(20));
        }
        self.harness.get_by_label(label).click_accesskit();
        self.frames(2);
    }

    /// Opens the combo box labelled `combo` (AccessKit) and picks `option` with a pointer click,
    /// as a user does (the popup closes on the click).
    pub fn choose(&mut self, combo: &str, option: &str) {
        self.click(combo);
        self.wait("the option", |g| g.has(option));
        self.harness.get_by_label(option).click();
        self.frames(3);
    }

    /// Sets the text of the field labelled `label` (AccessKit SetValue), then runs two frames.
    pub fn set_text(&mut self, label: &str, text: &str) {
        let t = Instant::now();
        while self.harness.query_by_label(label).is_none() {
            assert!(t.elapsed() < Duration::from_secs(20), "no field labelled {label:?}");
            self.harness.step();
            std::thread::sleep(Duration::from_millis(20));
        }
        self.harness.get_by_label(label).set_text_value_accesskit(text);
        self.frames(2);
    }

    /// Searches and selects the module whose tree node names `name` on `port`.
    pub fn select_module(&mut self, name: &str, port: u16) {
        self.select_module_at(name, ([127, 0, 0, 1], port).into());
    }

    /// Searches and selects the module whose tree node names `name` at `modbus`.
    pub fn select_module_at(&mut self, name: &str, modbus: SocketAddr) {
        self.click("Search the LAN");
        let node = format!("{name} ({modbus})");
        self.wait("the module in the tree", |g| g.has(&node));
        self.click(&node);
        self.wait("the module's tabs", |g| g.has("Network Settings"));
    }

    /// Answers the password dialog (which must name `module`, its name and MAC) with `password`.
    pub fn password(&mut self, module: &str, password: &str) {
        self.wait("the password dialog", |g| g.has("Configuration password"));
        assert!(self.has_part(module), "the password dialog names {module}");
        // Its field (the Security tab has a heading "Password" too).
        self.harness
            .query_all_by_role_and_label(egui::accesskit::Role::PasswordInput, "Password")
            .next()
            .expect("the dialog's password field")
            .set_text_value_accesskit(password);
        self.frames(2);
        self.click("OK");
        assert!(!self.has("Configuration password"), "the dialog closed");
    }

    /// The text of the progress bar, if one is shown.
    pub fn progress(&self) -> Option<String> {
        self.harness.query_all_by_role(egui::accesskit::Role::ProgressIndicator).next().and_then(|n| text(&n))
    }

    /// Whether the widget labelled `label` is enabled (AccessKit).
    pub fn enabled(&self, label: &str) -> bool {
        !self.harness.get_by_label(label).accesskit_node().is_disabled()
    }

    /// The status line's message (what the utility said last).
    pub fn said(&self) -> String {
        self.app().message().unwrap_or_default().to_string()
    }

    /// The text and the place (in points) of the first node whose text starts with `prefix`.
    pub fn text_starting(&self, prefix: &str) -> Option<(String, egui::Rect)> {
        self.harness
            .query_all_by_label_contains(prefix)
            .find_map(|n| text(&n).filter(|l| l.starts_with(prefix)).map(|l| (l, n.rect())))
    }

    /// The text in the field labelled `label`.
    pub fn field_value(&self, label: &str) -> String {
        self.harness.get_by_label(label).value().unwrap_or_default()
    }

    /// A label that starts with `prefix` and ends with `unit`.
    pub fn has_value(&self, prefix: &str, unit: &str) -> bool {
        self.harness
            .query_all_by_label_contains(prefix)
            .any(|n| text(&n).is_some_and(|l| l.starts_with(prefix) && l.ends_with(unit)))
    }

    /// The number in the label that starts with `prefix` and ends with `unit`.
    pub fn value_of(&self, prefix: &str, unit: &str) -> f64 {
        let node = self
            .harness
            .query_all_by_label_contains(prefix)
            .find(|n| text(n).is_some_and(|l| l.starts_with(prefix) && l.ends_with(unit)))
            .unwrap_or_else(|| panic!("no label {prefix}… {unit}"));
        let label = text(&node).unwrap_or_default();
        label[prefix.len()..label.len() - unit.len()].trim().parse().unwrap_or_else(|_| panic!("not a number: {label}"))
    }
}
