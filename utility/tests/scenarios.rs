//! The utility's GUI scenarios (issue #22), driven through AccessKit (egui_kittest, no window)
//! against the real simulated modules on loopback. What each scenario did is checked with
//! Modbus reads of the module's registers (tokio-modbus, not the utility's client), at the
//! addresses of spec/modules.md and spec/extensions.md (0-based PDU addresses, written as
//! literals here: 40025 = 0018h).

mod support;

use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use remodaq_utility::worker::Reading;
use support::*;

/// The scenarios whose figures are timings (s7's frames) or that load the machine (s10's
/// QEMU) run one at a time, not beside each other.
fn alone() -> MutexGuard<'static, ()> {
    static ALONE: Mutex<()> = Mutex::new(());
    ALONE.lock().unwrap_or_else(|e| e.into_inner())
}

/// A 32-bit value as the module's two registers, low word first (8350 spec §3.2).
fn words(v: u32) -> [u16; 2] {
    [v as u16, (v >> 16) as u16]
}

/// The pulse registers of DO n (8350 spec §3.2): low width 40025 + 2n, high width
/// 40037 + 2n, count 40049 + 2n.
fn pulse_low(n: u16) -> u16 {
    0x18 + 2 * n
}
fn pulse_high(n: u16) -> u16 {
    0x24 + 2 * n
}
fn pulse_count(n: u16) -> u16 {
    0x30 + 2 * n
}

/// Writes DO n's low width, high width (0.1 ms) and count over Modbus.
fn write_pulses(at: std::net::SocketAddr, n: u16, (low, high, count): (u32, u32, u32)) {
    for (reg, v) in [(pulse_low(n), low), (pulse_high(n), high), (pulse_count(n), count)] {
        write_registers(at, reg, &words(v)).unwrap_or_else(|e| panic!("DO{n} pulse register {reg:04X}h: {e:?}"));
    }
}

/// The panel's DO n fields hold these values: widths in ms (0.1 ms units), count.
fn assert_pulse_fields(gui: &Gui, n: u16, (low, high, count): (u32, u32, u32), when: &str) {
    for (what, ticks) in [("low", low), ("high", high)] {
        let text = gui.field_value(&format!("DO{n} {what}"));
        let shown: f64 = text.parse().unwrap_or_else(|_| panic!("DO{n} {what}: {text:?} is not a number"));
        let want = f64::from(ticks) / 10.0;
        assert!((shown - want).abs() < 1e-6, "{when}: DO{n} {what} shows {text} ms, the module holds {want} ms");
    }
    let text = gui.field_value(&format!("DO{n} count"));
    assert_eq!(text, count.to_string(), "{when}: DO{n} count");
}

/// Scenario 1: Search: both modules appear in the tree, under the host node.
#[test]
fn s1_search_finds_both_modules() {
    let m8318 = Sim::start("8318", "s1", &[]);
    let m8350 = Sim::start("8350", "s1", &[]);
    let mut gui = Gui::new(vec![m8318.discovery(), m8350.discovery()]);
    gui.click("Search the LAN");
    gui.wait("both modules in the tree", |g| {
        g.has(&format!("RemoDAQ-8318 (127.0.0.1:{})", m8318.port()))
            && g.has(&format!("RemoDAQ-8350 (127.0.0.1:{})", m8350.port()))
    });
    assert!(gui.has("Host (127.0.0.1)"), "the host node");
    // Through Modbus: each tree node's port serves the model it names (40211 = 00D2h).
    assert_eq!(holding(m8318.addr(), 0xD2, 1)[0], 0x8318);
    assert_eq!(holding(m8350.addr(), 0xD2, 1)[0], 0x8350);
}

/// Scenario 2: Select the 8350 and change its port: Setting with a wrong password shows the module's
/// answer, and nothing changes.
#[test]
fn s2_wrong_password_changes_nothing() {
    let m8350 = Sim::start("8350", "s2", &[]);
    let stored = discover(m8350.discovery()).stored_port;
    let mut gui = Gui::new(vec![m8350.discovery()]);
    gui.select_module("RemoDAQ-8350", m8350.port());
    let new_port = free_port();
    gui.set_text("Remote port", &new_port.to_string());
    gui.click("Setting");
    gui.set_text("Password", "not-the-password");
    gui.click("OK");
    gui.wait("the module's answer", |g| g.has_part("wrong password, nothing changed"));
    // Through Modbus: the module counted one failed authentication from this PC (00F9h =
    // 40250, docs/diagnostics.md), and it still serves Modbus on its old port.
    let d = holding(m8350.addr(), 0xF9, 1);
    assert_eq!(d[0], 1, "one failed authentication");
    assert_eq!(holding(m8350.addr(), 0xD2, 1)[0], 0x8350);
    // And its stored settings (a search) keep the old port.
    let found = discover(m8350.discovery());
    assert_eq!(found.stored_port, stored, "stored port unchanged");
}

/// Scenario 3: The right password, then ReStart: the utility searches again by itself, re-selects the
/// module by MAC and shows the new port in force; the panel's values match a Modbus read.
#[test]
fn s3_setting_restart_and_the_new_port() {
    let scenario = Scenario::new("s3-8350", "[di1]\nlevel = true\n");
    let mut m8350 = Sim::start_from_settings("8350", "s3", &scenario);
    let mac = remodaq_client::lan::Mac(discover(m8350.discovery()).mac);
    // Distinct pulse settings per DO before the utility starts (persisted: they survive the
    // restart below): the panel fills its empty fields with them.
    let first = |n: u16| (10 + u32::from(n), 20 + u32::from(n), u32::from(n));
    for n in 0..6 {
        write_pulses(m8350.addr(), n, first(n));
    }
    let mut gui = Gui::new(vec![m8350.discovery()]);
    gui.select_module("RemoDAQ-8350", m8350.port());
    let new_port = free_port();
    gui.set_text("Remote port", &new_port.to_string());
    gui.click("Setting");
    gui.set_text("Password", FACTORY_PASSWORD);
    gui.click("OK");
    gui.wait("stored", |g| g.has_part("network settings stored"));
    gui.click("ReStart");
    gui.set_text("Password", FACTORY_PASSWORD);
    gui.click("OK");
    m8350.wait_restarted();
    assert_eq!(m8350.port(), new_port, "the module listens on the new port");
    gui.wait("the module found again, in force on the new port", |g| {
        g.has_part("In force: ")
            && g.has_part(&format!("port {new_port}"))
            && g.has(&format!("RemoDAQ-8350 (127.0.0.1:{new_port})"))
    });
    // The panel, against a Modbus read of the same registers on the new port.
    gui.click("RemoDAQ-8350");
    gui.wait("the panel", |g| g.has("● DI1 ON"));
    let di = discrete(m8350.addr(), 0, 12);
    assert!(di[1] && !di[0], "DI1 high, DI0 low through Modbus: {di:?}");
    assert!(gui.has("● DI0 OFF"));
    // DO0-DO5: coils 00017-00022.
    let dos = coils(m8350.addr(), 0x10, 6);
    for (n, on) in dos.iter().enumerate() {
        assert!(gui.has(&format!("DO{n} {}", if *on { "ON" } else { "OFF" })), "DO{n} as Modbus reads it: {on}");
    }
    // Each DO's fields hold its own values (all six differ, in every field).
    for n in 0..6 {
        assert_pulse_fields(&gui, n, first(n), "filled from the module");
    }
    // New values with high words (32 bits, low word first), then each DO's Read button brings
    // its own into its row; the fields keep what they show until then.
    let second = |n: u16| {
        let n = u32::from(n);
        (0x1_0000 + 30 + n, 0x2_0000 + 40 + n, 0x3_0000 + 100 + n)
    };
    for n in 0..6 {
        write_pulses(m8350.addr(), n, second(n));
    }
    gui.wait("a reading after the new pulse values", |g| match g.app().latest(mac) {
        Some(Reading::Digital(d)) => d.outputs.iter().all(|o| o.count == 0x3_0000 + 100 + o.channel as u32),
        _ => false,
    });
    for n in 0..6 {
        assert_pulse_fields(&gui, n, first(n), "before Read");
    }
    for n in 0..6 {
        gui.click(&format!("Read DO{n}"));
        assert_pulse_fields(&gui, n, second(n), &format!("after Read DO{n}"));
        for other in n + 1..6 {
            assert_pulse_fields(&gui, other, first(other), &format!("DO{other} after Read DO{n}"));
        }
    }
    gui.click("Diagnostics");
    // Reset cause (00F3h, extensions §1): 2 after a software restart.
    let cause = holding(m8350.addr(), 0xF3, 1)[0];
    assert_eq!(cause, 2, "a software restart");
    gui.wait("the reset cause", |g| g.has("Reset cause: software restart"));
}

/// Scenario 4: Select the 8318, set type K and Setting: an open channel shows "open", and a 40 mV
/// channel shows the NIST temperature.
#[test]
fn s4_type_k_open_and_nist() {
    let scenario = Scenario::new("s4-8318", "cjc_celsius = 0.0\n[ch0]\nopen = true\n[ch1]\nmillivolts = 40.0\n");
    let m8318 = Sim::start("8318", "s4", &["--scenario", scenario.path()]);
    let mut gui = Gui::new(vec![m8318.discovery()]);
    gui.select_module("RemoDAQ-8318", m8318.port());
    gui.click("RemoDAQ-8318");
    gui.wait("the panel", |g| g.has_part("CH1 "));
    gui.choose("Input range", "0F thermocouple K");
    gui.click("Setting");
    gui.wait("type K in force", |g| g.has_value("CH1 ", "°C") && g.has("CH0 open"));
    // Through Modbus: type code 0Fh (40201) and channel 0's status open (40225 = 1).
    assert_eq!(holding(m8318.addr(), 0xC8, 1)[0], 0x0F);
    assert_eq!(holding(m8318.addr(), 0xE0, 1)[0], 1);
    let expected = nist_k_temperature(40.0);
    let shown = gui.value_of("CH1 ", "°C");
    eprintln!("s4: CH1 at 40.000 mV, type K, 0 °C terminals: shows {shown} °C, NIST table {expected:.3} °C");
    assert!((shown - expected).abs() <= 0.1, "CH1 shows {shown} °C, NIST {expected:.2} °C");
}

/// Scenario 5: Toggle DO1 and write a pulse train: a Modbus read confirms both.
#[test]
fn s5_do_toggle_and_pulse_train() {
    let m8350 = Sim::start("8350", "s5", &[]);
    let mut gui = Gui::new(vec![m8350.discovery()]);
    gui.select_module("RemoDAQ-8350", m8350.port());
    gui.click("RemoDAQ-8350");
    gui.wait("the panel", |g| g.has("DO1 OFF"));
    gui.click("DO1 OFF");
    gui.wait("DO1 on", |g| g.has("DO1 ON"));
    assert!(coils(m8350.addr(), 0x11, 1)[0], "DO1 (00018) on");
    gui.set_text("DO2 low", "2.5");
    gui.set_text("DO2 high", "1.5");
    gui.set_text("DO2 count", "100");
    gui.click("Write DO2");
    gui.wait("written", |g| g.has_part("DO2 pulses"));
    // 0.1 ms units, 32-bit low word first (spec §3.2).
    assert_eq!(holding(m8350.addr(), pulse_low(2), 2), [25, 0]);
    assert_eq!(holding(m8350.addr(), pulse_high(2), 2), [15, 0]);
    assert_eq!(holding(m8350.addr(), pulse_count(2), 2), [100, 0]);
}

/// Scenario 6: Arm a latch, drive the input, and see `L-H ON` until Clear.
#[test]
fn s6_latch_until_clear() {
    let scenario = Scenario::new("s6-8350", "[di3]\nlevel = false\n");
    let m8350 = Sim::start("8350", "s6", &["--scenario", scenario.path()]);
    let mut gui = Gui::new(vec![m8350.discovery()]);
    gui.select_module("RemoDAQ-8350", m8350.port());
    gui.click("RemoDAQ-8350");
    gui.wait("the panel", |g| g.has("● DI3 OFF"));
    gui.choose("DI3 mode", "Latch L-H");
    gui.wait("the mode", |g| g.has_part("DI3 mode"));
    let wait_mode = Instant::now();
    while holding(m8350.addr(), 0x100 + 3, 1)[0] != 2 {
        assert!(wait_mode.elapsed() < Duration::from_secs(10), "DI3 in latch-rising mode (40260 = 2)");
        gui.frames(5);
    }
    assert!(gui.has("DI3 latch —"));
    scenario.write("[di3]\nlevel = true\n");
    gui.wait("the latch", |g| g.has("DI3 latch L-H ON"));
    scenario.write("[di3]\nlevel = false\n");
    gui.wait("the input low again", |g| g.has("● DI3 OFF"));
    gui.frames_for(Duration::from_secs(1));
    assert!(gui.has("DI3 latch L-H ON"), "held until Clear");
    gui.click("Clear latch DI3");
    gui.wait("cleared", |g| g.has("DI3 latch —"));
    gui.frames_for(Duration::from_millis(500));
    assert!(gui.has("DI3 latch —"));
    // Through Modbus: the latch flag (00036 + 4n) is clear.
    assert!(!coils(m8350.addr(), 0x23 + 4 * 3, 1)[0]);
}

/// Scenario 7: A module that stops answering mid-poll (stopped with SIGSTOP: its sockets stay
/// open, so every exchange waits for the timeout, as with a hung module or a pulled cable)
/// shows "no answer"; the UI keeps running, no frame waits on the network, and the other
/// module goes on being read. Let run again (SIGCONT), it is read again.
#[test]
fn s7_module_stopped_mid_poll() {
    let _alone = alone();
    let mut m8350 = Sim::start("8350", "s7", &[]);
    let m8318 = Sim::start("8318", "s7", &[]);
    let other = remodaq_client::lan::Mac(discover(m8318.discovery()).mac);
    let stopped = remodaq_client::lan::Mac(discover(m8350.discovery()).mac);
    let port = m8350.port();
    let mut gui = Gui::new(vec![m8350.discovery(), m8318.discovery()]);
    gui.select_module("RemoDAQ-8350", port);
    gui.click("RemoDAQ-8350");
    gui.wait("the panel", |g| g.has("DO0 OFF"));
    let uptime = |g: &Gui, mac| match g.app().latest(mac) {
        Some(Reading::Analog(a)) => a.diagnostics.uptime_s,
        Some(Reading::Digital(d)) => d.diagnostics.uptime_s,
        _ => 0,
    };
    let resumable = m8350.stop();
    let gone = Instant::now();
    let mut longest = Duration::ZERO;
    let mut frames = 0u32;
    while !gui.has_part("no answer") {
        let t = Instant::now();
        gui.frames(1);
        longest = longest.max(t.elapsed());
        frames += 1;
        assert!(gone.elapsed() < Duration::from_secs(10), "no \"no answer\" within 10 s");
        std::thread::sleep(Duration::from_millis(10));
    }
    let shown_after = gone.elapsed();
    // Frames keep coming while the worker's exchanges with the stopped module wait out their
    // timeouts.
    let more = Instant::now();
    let mut later = 0u32;
    let before = uptime(&gui, other);
    while more.elapsed() < Duration::from_millis(3500) {
        let t = Instant::now();
        gui.frames(1);
        longest = longest.max(t.elapsed());
        later += 1;
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(uptime(&gui, other) > before, "the 8318 is still read (uptime {before} s, then {} s)", uptime(&gui, other));
    assert!(gui.has(&format!("RemoDAQ-8350 (127.0.0.1:{port}) — no answer")), "the tree says it");
    let ui_longest = gui.app().stats.longest_ui;
    eprintln!(
        "utility-frames: module stopped (SIGSTOP: {resumable}); \"no answer\" after {:.0} ms (timeout {} ms); {frames} frames \
         before, {later} in the next 3.5 s; longest frame step {:.2} ms, longest UI pass {:.2} ms",
        shown_after.as_secs_f64() * 1e3,
        TIMEOUT.as_millis(),
        longest.as_secs_f64() * 1e3,
        ui_longest.as_secs_f64() * 1e3
    );
    // A frame never waits on the network: a read on the UI thread would take the timeout
    // (500 ms) here, where the module's sockets accept and never answer.
    assert!(longest < Duration::from_millis(100), "a frame took {longest:?} while the module was stopped");
    if resumable {
        // The module runs again: read again (a reading newer than any before the stop, and
        // "no answer" gone from the tree and the panel).
        let last = uptime(&gui, stopped);
        m8350.resume();
        gui.wait("the module read again", |g| !g.has_part("no answer") && uptime(g, stopped) > last);
        assert!(gui.has(&format!("RemoDAQ-8350 (127.0.0.1:{port})")), "the tree without \"no answer\"");
        assert!(gui.has("DO0 OFF"), "the panel");
    } else {
        // Windows: no SIGSTOP, the module was killed (connections refused at once).
        not_applicable("s7: the module read again after SIGCONT", "no SIGSTOP here: the module was killed");
    }
}

/// A module's name and MAC as the password dialog names it.
fn named(name: &str, mac: [u8; 6]) -> String {
    format!("{name} ({})", remodaq_client::lan::Mac(mac))
}

/// A configuration command of the test's own (discovery protocol, `remodaq_client::lan`): the
/// module's allow-list, read with `password`.
fn allow_list(discovery: std::net::SocketAddr, mac: [u8; 6], password: &str) -> Result<Vec<String>, String> {
    use remodaq_client::lan::{command, Command, Mac};
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
    runtime
        .block_on(command(discovery, None, Mac(mac), Some(password), Command::GetAccess, Duration::from_secs(5)))
        .map(|o| o.list.map(|l| l.iter().map(|n| n.to_string()).collect()).unwrap_or_default())
        .map_err(|e| e.to_string())
}

/// Scenario 8: The Security tab. A new password, checked as it is typed (8 characters or more,
/// the same twice), stored after the old one is given; then the Modbus write allow-list:
/// checked (an address that is none, five networks), stored and in force (extensions §4: a
/// write from this PC, outside it, answers exception 01 and changes nothing), read back into
/// its field, and replaced by one that holds this PC.
#[test]
fn s8_security_password_and_allow_list() {
    const NEW: &str = "s8-new-password";
    let m8350 = Sim::start("8350", "s8", &[]);
    let found = discover(m8350.discovery());
    assert!(found.factory_password && !found.writes_restricted, "a factory module");
    let dialog = named("RemoDAQ-8350", found.mac);
    let mut gui = Gui::new(vec![m8350.discovery()]);
    gui.select_module("RemoDAQ-8350", m8350.port());
    gui.click("Security");

    // The password, as typed.
    gui.set_text("New password", "7-chars");
    gui.wait("too short", |g| g.has("At least 8 characters"));
    assert!(!gui.enabled("Change password"), "7 characters: no change");
    gui.set_text("New password", NEW);
    gui.set_text("New password again", "s8-new-passworD");
    gui.wait("differ", |g| g.has("The two new passwords differ"));
    assert!(!gui.enabled("Change password"), "two different passwords: no change");
    gui.set_text("New password again", NEW);
    assert!(gui.enabled("Change password"), "the same twice");
    gui.click("Change password");
    gui.password(&dialog, FACTORY_PASSWORD);
    gui.wait("the module's answer", |g| g.said() == "password changed");
    assert!(gui.field_value("New password").is_empty() && gui.field_value("New password again").is_empty());
    // The module's own word: no longer the factory password; the new one logs in, the old one
    // does not.
    assert!(!discover(m8350.discovery()).factory_password, "the search flag: not the factory password");
    assert_eq!(allow_list(m8350.discovery(), found.mac, NEW), Ok(vec![]), "the new password logs in");
    assert!(allow_list(m8350.discovery(), found.mac, FACTORY_PASSWORD).is_err(), "the old one no longer does");

    // The allow-list: checked before anything is asked.
    gui.set_text("Allowed networks", "10.0.0.300");
    gui.click("Store list");
    gui.wait("not a network", |g| g.said().contains("is not an IPv4 network"));
    gui.set_text("Allowed networks", "10.0.0.1, 10.0.0.2, 10.0.0.3, 10.0.0.4, 10.0.0.5");
    gui.click("Store list");
    gui.wait("five networks", |g| g.said() == "At most 4 networks");
    assert!(!gui.has("Configuration password"), "nothing asked");
    assert_eq!(allow_list(m8350.discovery(), found.mac, NEW), Ok(vec![]), "nothing stored");

    // Two networks without this PC: stored and in force.
    gui.set_text("Allowed networks", "10.0.0.5, 192.168.7.0/24");
    gui.click("Store list");
    gui.password(&dialog, NEW);
    gui.wait("stored", |g| g.said() == "Modbus writes allowed only from: 10.0.0.5/32, 192.168.7.0/24");
    assert_eq!(
        allow_list(m8350.discovery(), found.mac, NEW),
        Ok(vec!["10.0.0.5/32".to_string(), "192.168.7.0/24".to_string()]),
        "the module's list"
    );
    assert!(discover(m8350.discovery()).writes_restricted, "the search flag: writes restricted");
    // DO0 (coil 00017): the write is refused with exception 01 and changes nothing; reads work.
    assert_eq!(write_coil(m8350.addr(), 0x10, true), Err(ExceptionCode::IllegalFunction), "a write from 127.0.0.1");
    assert!(!coils(m8350.addr(), 0x10, 1)[0], "DO0 unchanged");

    // Read back into the field.
    gui.set_text("Allowed networks", "");
    gui.click("Read list");
    gui.password(&dialog, NEW);
    gui.wait("the list read", |g| g.field_value("Allowed networks") == "10.0.0.5/32, 192.168.7.0/24");

    // A list that holds this PC: its writes are served again.
    gui.set_text("Allowed networks", "127.0.0.0/8");
    gui.click("Store list");
    gui.password(&dialog, NEW);
    gui.wait("stored", |g| g.said() == "Modbus writes allowed only from: 127.0.0.0/8");
    assert_eq!(write_coil(m8350.addr(), 0x10, true), Ok(()), "a write from 127.0.0.1, inside 127.0.0.0/8");
    assert!(coils(m8350.addr(), 0x10, 1)[0], "DO0 on");
}

/// Scenario 11: the MQTT tab (issue #40) against the simulated 8350 and Debian's mosquitto:
/// the settings read through the module's web console (after its password was set: not with
/// the factory one), changed in the form (on, the broker on this PC, TLS off, a prefix of the
/// test's, a 500 ms period), stored: the module comes online on the broker under that prefix;
/// read again, the form shows what the module holds. The window is saved as a picture
/// (target/utility-mqtt-tab.png) to look at.
#[test]
fn s11_mqtt_tab() {
    use remodaq_mqtt::testing::{Broker, Subscriber};
    const PASSWORD: &str = "s11-password";
    let _alone = alone();
    let broker = Broker::start();
    let sub = Subscriber::with_args(broker.port, &["-t", "test/gui/#"]);
    let m8350 = Sim::start("8350", "s11", &["--http", "127.0.0.1:0"]);
    let web = m8350.web().expect("the web console");
    let mut page = remodaq_board_host::testing::web::log_in(web, FACTORY_PASSWORD)
        .unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    assert_eq!(page.change_password(web, PASSWORD, [11; 16]).status, 204);
    let found = discover(m8350.discovery());
    let dialog = named("RemoDAQ-8350", found.mac);
    let mut gui = Gui::new(vec![m8350.discovery()]);
    gui.select_module("RemoDAQ-8350", m8350.port());
    gui.click("MQTT");
    gui.set_text("Web console", &web.to_string());
    gui.click("Read MQTT settings");
    gui.password(&dialog, PASSWORD);
    gui.wait("the settings read", |g| g.said() == "MQTT settings as the module holds them");
    // docs/mqtt.md's defaults: off, TLS on port 8883, a 10 s period.
    assert_eq!((gui.field_value("Port"), gui.field_value("Period (ms)")), ("8883".into(), "10000".into()));
    gui.click("Publish to the broker");
    gui.click("TLS");
    gui.set_text("Broker address", "127.0.0.1");
    gui.set_text("Port", &broker.port.to_string());
    gui.set_text("Topic prefix", "test/gui");
    gui.set_text("Period (ms)", "500");
    gui.click("Store MQTT settings");
    gui.password(&dialog, PASSWORD);
    gui.wait("stored", |g| g.said() == "MQTT settings as the module holds them");
    let online = sub.next_on("test/gui/status", Duration::from_secs(15)).expect("online under the prefix set");
    assert!(online.1.contains(r#""state":"online""#), "{online:?}");
    gui.set_text("Period (ms)", "");
    gui.click("Read MQTT settings");
    gui.password(&dialog, PASSWORD);
    gui.wait("read again", |g| g.field_value("Period (ms)") == "500");
    assert_eq!(gui.field_value("Topic prefix"), "test/gui");
    gui.frames(3);
    if let Ok(image) = gui.harness.render() {
        let file = workspace().join("target").join("utility-mqtt-tab.png");
        let _ = image.save(&file);
        eprintln!("the MQTT tab: {}", file.display());
    }
}

/// The update service's port (docs/update.md).
const UPDATE_PORT: u16 = 8301;

/// Scenario 9: The Firmware tab against the host build, which serves no updates (a simulated
/// module has no bootloader): the version of the module selected; a file that is not a signed
/// image and an image for the other model (`remodaq sign`, test key) refused before any
/// password is asked; an image for the module selected goes to that module, not to the one
/// selected before (the utility's own model check in the client passes: the 8318 answers), a
/// progress bar while it is under way (no second update meanwhile), and the reason it failed.
/// A real update, and the module's own refusals, are s10's (QEMU).
#[test]
fn s9_firmware_tab_on_the_host_build() {
    let m8350 = Sim::start("8350", "s9", &[]);
    let m8318 = Sim::start("8318", "s9", &[]);
    let mac8318 = discover(m8318.discovery()).mac;
    let payload = temp("s9-firmware.bin");
    std::fs::write(&payload, vec![0x5A; 20_000]).expect("payload");
    let (for_8318, for_8350, not_an_image) = (temp("s9-8318.rdq"), temp("s9-8350.rdq"), temp("s9-text.rdq"));
    sign(&payload, "8318", "A101", 2, &for_8318);
    sign(&payload, "8350", "A101", 2, &for_8350);
    std::fs::write(&not_an_image, "not a firmware image\n").expect("text file");
    // Nothing serves updates on this PC, so the reason shown is the host build's.
    let update_at = std::net::SocketAddr::from(([127, 0, 0, 1], UPDATE_PORT));
    assert!(
        std::net::TcpStream::connect_timeout(&update_at, Duration::from_secs(1)).is_err(),
        "something listens on {update_at}: this scenario needs the port free"
    );
    let mut gui = Gui::new(vec![m8350.discovery(), m8318.discovery()]);
    gui.select_module("RemoDAQ-8350", m8350.port());
    gui.click(&format!("RemoDAQ-8318 (127.0.0.1:{})", m8318.port()));
    gui.click("Firmware");
    // 40213 = A100h (spec §2.1).
    gui.wait("the 8318's firmware tab", |g| {
        g.has_part(&format!("RemoDAQ-8318 — {}", remodaq_client::lan::Mac(mac8318))) && g.has("Firmware version: A100")
    });
    assert!(!gui.enabled("Update"), "no file: no update");

    gui.set_text("Image file", not_an_image.to_str().expect("utf-8"));
    gui.click("Update");
    gui.wait("refused", |g| g.said().contains("is not a signed image file"));
    assert!(!gui.has("Configuration password"), "no password asked");

    gui.set_text("Image file", for_8350.to_str().expect("utf-8"));
    gui.click("Update");
    gui.wait("the model check", |g| g.said() == "The image is for a 8350");
    assert!(!gui.has("Configuration password"), "no password asked");
    assert!(gui.progress().is_none(), "nothing under way");

    gui.set_text("Image file", for_8318.to_str().expect("utf-8"));
    gui.click("Update");
    gui.password(&named("RemoDAQ-8318", mac8318), FACTORY_PASSWORD);
    gui.wait("under way", |g| g.progress().is_some());
    assert!(!gui.enabled("Update"), "one update at a time");
    let started = Instant::now();
    gui.wait("the reason", |g| g.progress().is_none());
    let said = gui.said();
    eprintln!("s9: after {:.1} s: {said}", started.elapsed().as_secs_f64());
    assert!(
        said.contains(&format!("cannot connect to the update service at {update_at}")),
        "the 8318 (the module selected) was asked, and it has no update service: {said}"
    );
    assert!(gui.enabled("Update"), "another try allowed");
    assert_eq!(holding(m8318.addr(), 0xD4, 1)[0], 0xA100, "the 8318 still runs A100 (40213)");
    assert_eq!(holding(m8350.addr(), 0xD4, 1)[0], 0xA100, "the 8350 still runs A100 (40213)");
}

/// QEMU running the QEMU board's bootloader and an 8350 image (scripts/qemu build); killed
/// when dropped.
struct Qemu(std::process::Child);

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Scenario 10: A real update through the Firmware tab, against the 8350 image on the QEMU
/// board (its update service and bootloader), built by `scripts/qemu build` and
/// `scripts/qemu variants` into target/images/qemu. Ignored by a plain `cargo test` (the host
/// tests run before the images are built); the test command runs it after them with
/// `--ignored`, where a missing image or QEMU is a failure, never a pass. The module's refusals
/// shown (the factory password still in force, a changed file, a wrong password), the password
/// set in the Security tab, then A100 -> A101 with its progress, and the version before and
/// after.
// The QEMU module is reached at a loopback address of its own (127.83.x.y), which needs Linux.
#[cfg(target_os = "linux")]
#[test]
#[ignore = "needs the QEMU images (scripts/qemu build, scripts/qemu variants): the test command runs it after them"]
fn s10_firmware_update_on_qemu() {
    let images = workspace().join("target/images/qemu");
    let (bootloader, seed, v2, v2_bin) = (
        images.join("remodaq-qemu-bootloader"),
        images.join("firmware-8350.bin"),
        images.join("firmware-8350-v2.rdq"),
        images.join("firmware-8350-v2.bin"),
    );
    let missing: Vec<String> =
        [&bootloader, &seed, &v2].iter().filter(|p| !p.exists()).map(|p| p.display().to_string()).collect();
    assert!(missing.is_empty(), "absent: {} (scripts/qemu build, then scripts/qemu variants)", missing.join(", "));
    let qemu =
        std::process::Command::new("qemu-system-arm").arg("--version").output().is_ok_and(|o| o.status.success());
    assert!(qemu, "no qemu-system-arm");
    let _alone = alone();
    const NEW: &str = "s10-update-password";
    // The module at a loopback address of this run's own, on the ports the utility uses for
    // any module (Modbus 8000, discovery 8300, updates 8301).
    let pid = std::process::id();
    let ip = std::net::Ipv4Addr::new(127, 83, (pid >> 8) as u8, (pid as u8).max(1));
    let (modbus, discovery) = (std::net::SocketAddr::from((ip, 8000)), std::net::SocketAddr::from((ip, 8300)));
    let log = temp("s10-qemu.log");
    let out = std::fs::File::create(&log).expect("log");
    let _qemu = Qemu(
        std::process::Command::new("qemu-system-arm")
            .args(["-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null"])
            .args(["-semihosting-config", "enable=on,target=native"])
            .arg("-nic")
            .arg(format!(
                "user,id=nic0,model=lan9118,hostfwd=tcp:{ip}:8000-:8000,hostfwd=udp:{ip}:8300-:8300,hostfwd=tcp:{ip}:{UPDATE_PORT}-:{UPDATE_PORT}"
            ))
            .arg("-kernel")
            .arg(&bootloader)
            .arg("-device")
            .arg(format!("loader,file={},addr=0x300000", seed.display()))
            .stdin(std::process::Stdio::null())
            .stdout(out.try_clone().expect("log"))
            .stderr(out)
            .spawn()
            .expect("qemu-system-arm starts"),
    );
    let found = discover_within(discovery, 120).unwrap_or_else(|| {
        panic!(
            "the QEMU module did not answer a search within 60 s: {}",
            std::fs::read_to_string(&log).unwrap_or_default()
        )
    });
    assert_eq!((found.model, found.version), (0x8350, 0xA100), "the seed image: an 8350 running A100");
    let dialog = named("RemoDAQ-8350", found.mac);
    let version = || holding(modbus, 0xD4, 1)[0];
    let mut gui =
        Gui::with(vec![discovery], eframe::egui::vec2(1280.0, 900.0), Duration::from_secs(2), Clock::default());
    gui.select_module_at("RemoDAQ-8350", modbus);
    gui.click("Firmware");
    gui.wait("the version", |g| g.has("Firmware version: A100"));
    let image = |gui: &mut Gui, file: &std::path::Path| {
        gui.set_text("Image file", file.to_str().expect("utf-8"));
        gui.click("Update");
    };
    let refused = |gui: &mut Gui, what: &str, reason: &str| {
        gui.wait_for(what, Duration::from_secs(60), |g| g.progress().is_none() && g.said().contains(reason));
        assert_eq!(version(), 0xA100, "{what}: nothing changed");
    };

    // Refused by the module while the factory password is in force.
    image(&mut gui, &v2);
    gui.password(&dialog, FACTORY_PASSWORD);
    refused(&mut gui, "the factory password's refusal", "the factory password is in force");

    // A password, through the Security tab.
    gui.click("Security");
    gui.set_text("New password", NEW);
    gui.set_text("New password again", NEW);
    gui.click("Change password");
    gui.password(&dialog, FACTORY_PASSWORD);
    gui.wait_for("the password changed", Duration::from_secs(30), |g| g.said() == "password changed");
    gui.click("Firmware");

    // A changed file: the module checks the signature once it has all of it.
    let bytes = std::fs::read(&v2).expect("v2");
    let mut changed = bytes.clone();
    *changed.last_mut().expect("bytes") ^= 1;
    let tampered = temp("s10-tampered.rdq");
    std::fs::write(&tampered, &changed).expect("tampered");
    image(&mut gui, &tampered);
    gui.password(&dialog, NEW);
    refused(&mut gui, "a changed file's refusal", "the signature does not match");

    // A wrong password.
    image(&mut gui, &v2);
    gui.password(&dialog, "not-the-password");
    refused(&mut gui, "a wrong password's refusal", "wrong password, nothing changed");

    // The update: progress, then the version before and after.
    image(&mut gui, &v2);
    gui.password(&dialog, NEW);
    let seen = std::cell::RefCell::new(Vec::<String>::new());
    gui.wait_for("the update", Duration::from_secs(300), |g| {
        if let Some(p) = g.progress() {
            if seen.borrow().last() != Some(&p) {
                seen.borrow_mut().push(p);
            }
        }
        g.progress().is_none()
    });
    let said = gui.said();
    let seen = seen.into_inner();
    eprintln!("s10: progress {seen:?}; then: {said}");
    assert_eq!(said, "Firmware A100 → A101", "the version before and after");
    assert_eq!(version(), 0xA101, "40213 after the update");
    // The bar: "sent / total B" while sending (from "0 / 1 B" before the module's first
    // answer; the sending itself may fall between two frames), then the module's check and
    // restart, which the tool waits out (1 s at least).
    assert!(seen.iter().any(|p| p == "verifying, then restarting…"), "the bar went on to the module's check: {seen:?}");
    let sent: Vec<(u64, u64)> = seen
        .iter()
        .filter_map(|p| {
            let (a, b) = p.strip_suffix(" B")?.split_once(" / ")?;
            Some((a.parse().ok()?, b.parse().ok()?))
        })
        .filter(|(a, _)| *a > 0)
        .collect();
    let total = std::fs::metadata(&v2_bin).map(|m| m.len()).ok();
    for (a, b) in sent {
        assert!(a <= b && total.is_none_or(|t| b == t), "{a} / {b} B shown, the firmware is {total:?} bytes: {seen:?}");
    }
    // A search shows the new version in the tab.
    gui.click("Search the LAN");
    gui.wait("the version after a search", |g| g.has("Firmware version: A101"));
}
