//! The utility's GUI scenarios (issue #22), driven through AccessKit (egui_kittest, no window)
//! against the real simulated modules on loopback. What each scenario did is checked with
//! Modbus reads of the module's registers (tokio-modbus, not the utility's client), at the
//! addresses of spec/modules.md and spec/extensions.md.

mod support;

use std::time::{Duration, Instant};

use support::*;

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
    // Through Modbus: each tree node's port serves the model it names (40211).
    assert_eq!(holding(m8318.addr(), REG_NAME, 1)[0], 0x8318);
    assert_eq!(holding(m8350.addr(), REG_NAME, 1)[0], 0x8350);
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
    // Through Modbus: the module counted one failed authentication from this PC (40xxx of
    // extensions §1), and it still serves Modbus on its old port.
    let d = holding(m8350.addr(), diag::REG_AUTH_FAILURES, 1);
    assert_eq!(d[0], 1, "one failed authentication");
    assert_eq!(holding(m8350.addr(), REG_NAME, 1)[0], 0x8350);
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
    let dos = coils(m8350.addr(), m8350::Point::Do(0).addr().1, 6);
    for (n, on) in dos.iter().enumerate() {
        assert!(gui.has(&format!("DO{n} {}", if *on { "ON" } else { "OFF" })), "DO{n} as Modbus reads it: {on}");
    }
    // The pulse fields against 40025.. (low), 40037.. (high), 40049.. (count): 0.1 ms units.
    for n in 0..6u8 {
        for (field, what, scale) in [
            (m8350::PulseField::Low, "low", 10.0),
            (m8350::PulseField::High, "high", 10.0),
            (m8350::PulseField::Count, "count", 1.0),
        ] {
            let w = holding(m8350.addr(), m8350::Point::Pulse(field, n, m8350::Word::Low).addr().1, 2);
            let expected = f64::from(u32::from(w[0]) | u32::from(w[1]) << 16) / scale;
            let shown: f64 = gui.field_value(&format!("DO{n} {what}")).parse().expect("a number");
            assert_eq!(shown, expected, "DO{n} {what}");
        }
    }
    gui.click("Diagnostics");
    let cause = holding(m8350.addr(), diag::REG_RESET_CAUSE, 1)[0];
    assert_eq!(cause, diag::reset_cause::SOFTWARE, "a software restart");
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
    assert_eq!(holding(m8318.addr(), m8318::REG_INPUT_TYPE, 1)[0], 0x0F);
    assert_eq!(holding(m8318.addr(), m8318::REG_STATUS, 1)[0], 1);
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
    assert!(coils(m8350.addr(), m8350::Point::Do(1).addr().1, 1)[0], "DO1 (00018) on");
    gui.set_text("DO2 low", "2.5");
    gui.set_text("DO2 high", "1.5");
    gui.set_text("DO2 count", "100");
    gui.click("Write DO2");
    gui.wait("written", |g| g.has_part("DO2 pulses"));
    // 0.1 ms units, 32-bit low word first (spec §3.4).
    let low = m8350::Point::Pulse(m8350::PulseField::Low, 2, m8350::Word::Low).addr().1;
    let high = m8350::Point::Pulse(m8350::PulseField::High, 2, m8350::Word::Low).addr().1;
    let count = m8350::Point::Pulse(m8350::PulseField::Count, 2, m8350::Word::Low).addr().1;
    assert_eq!(holding(m8350.addr(), low, 2), [25, 0]);
    assert_eq!(holding(m8350.addr(), high, 2), [15, 0]);
    assert_eq!(holding(m8350.addr(), count, 2), [100, 0]);
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
    while holding(m8350.addr(), m8350::REG_DI_MODE + 3, 1)[0] != 2 {
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
    assert!(!coils(m8350.addr(), m8350::Point::Latch(3).addr().1, 1)[0]);
}

/// Scenario 7: A module that goes away mid-poll shows "no answer"; the UI keeps running, no frame waits
/// on the network, and the other module goes on being read.
#[test]
fn s7_module_gone_mid_poll() {
    let m8350 = Sim::start("8350", "s7", &[]);
    let m8318 = Sim::start("8318", "s7", &[]);
    let other = remodaq_client::lan::Mac(discover(m8318.discovery()).mac);
    let port = m8350.port();
    let mut gui = Gui::new(vec![m8350.discovery(), m8318.discovery()]);
    gui.select_module("RemoDAQ-8350", port);
    gui.click("RemoDAQ-8350");
    gui.wait("the panel", |g| g.has("DO0 OFF"));
    m8350.kill();
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
    // Frames keep coming while the worker retries the dead module.
    let more = Instant::now();
    let mut later = 0u32;
    let uptime = |g: &Gui| match g.app().latest(other) {
        Some(remodaq_utility::worker::Reading::Analog(a)) => a.diagnostics.uptime_s,
        _ => 0,
    };
    let before = uptime(&gui);
    while more.elapsed() < Duration::from_millis(3500) {
        let t = Instant::now();
        gui.frames(1);
        longest = longest.max(t.elapsed());
        later += 1;
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(uptime(&gui) > before, "the 8318 is still read (uptime {before} s, then {} s)", uptime(&gui));
    assert!(gui.has(&format!("RemoDAQ-8350 (127.0.0.1:{port}) — no answer")), "the tree says it");
    let ui_longest = gui.app().stats.longest_ui;
    eprintln!(
        "utility-frames: \"no answer\" after {:.0} ms (timeout {} ms); {frames} frames before, {later} in the next 3.5 s; \
         longest frame step {:.2} ms, longest UI pass {:.2} ms",
        shown_after.as_secs_f64() * 1e3,
        TIMEOUT.as_millis(),
        longest.as_secs_f64() * 1e3,
        ui_longest.as_secs_f64() * 1e3
    );
    // A frame never waits on the network: far below the module timeout, whatever the machine.
    assert!(longest < TIMEOUT / 2, "a frame took {longest:?}");
}
