//! Snapshot images of the utility's main views (issue #22), rendered with wgpu (Mesa's
//! software Vulkan on Linux) and compared with the committed images in `tests/snapshots/`
//! with a tolerance for what is live (uptime, counters, the trend's curve). `UPDATE_SNAPSHOTS=1`
//! writes new ones; look at them before committing.

mod support;

use std::time::Duration;

use egui_kittest::SnapshotOptions;
use support::*;

fn options(max_failed_pixels: usize) -> SnapshotOptions {
    SnapshotOptions::new().max_failed_pixels(max_failed_pixels)
}

#[test]
fn snapshots_of_the_main_views() {
    let s8318 = Scenario::new(
        "snap-8318",
        "cjc_celsius = 24.5\n[ch0]\nopen = true\n[ch1]\nmillivolts = 40.0\n[ch2]\nmillivolts = 1.0\n[ch3]\nmillivolts = 12.2\n",
    );
    let s8350 = Scenario::new("snap-8350", "[di1]\nlevel = true\n[di4]\nlevel = true\n");
    // Fixed ports (the tree shows them), below Linux's ephemeral range (32768-) and above the
    // QEMU tests' (20000-31999).
    let m8318 = Sim::start_at("8318", "snap", 32318, 32319, &["--scenario", s8318.path()]);
    let m8350 = Sim::start_at("8350", "snap", 32350, 32351, &["--scenario", s8350.path()]);
    let mut gui = Gui::sized(vec![m8318.discovery(), m8350.discovery()], eframe::egui::vec2(1100.0, 760.0));

    // The main window: the tree and a module's network settings.
    gui.select_module("RemoDAQ-8318", m8318.port());
    gui.frames(5);
    gui.harness.snapshot_options("main_window", &options(1500));

    // The 8318 panel, type K, live values.
    gui.click("RemoDAQ-8318");
    gui.choose("Input range", "0F thermocouple K");
    gui.click("Setting");
    gui.wait("type K values", |g| g.has("CH0 open") && g.has_value("CH1 ", "°C"));
    gui.frames_for(Duration::from_millis(500));
    gui.harness.snapshot_options("panel_8318", &options(2500));

    // The 8350 panel.
    let node = format!("RemoDAQ-8350 (127.0.0.1:{})", m8350.port());
    gui.click(&node);
    gui.click("RemoDAQ-8350");
    gui.wait("the 8350 panel", |g| g.has("● DI1 ON"));
    gui.frames_for(Duration::from_millis(500));
    gui.harness.snapshot_options("panel_8350", &options(2500));

    // A trend of more than 30 s: the 8318's CH3 follows a slow wave written to its scenario,
    // one step a second on the utility's own clock (the trend's time axis), so that the curve,
    // the grid and the values' range fall at the same places in every run. The wave starts at a
    // multiple of 10 s with 25 s or more of steady value before it, and the trend is paused
    // 40 s later, showing its last minute (which starts after the series' first point).
    gui.click(&format!("RemoDAQ-8318 (127.0.0.1:{})", m8318.port()));
    gui.click("Trends");
    let name = &format!("RemoDAQ-8318 (127.0.0.1:{}) CH3 (°C)", m8318.port());
    gui.click(name);
    let start = ((gui.app().now_s() + 25.0) / 10.0).ceil() * 10.0;
    let end = start + 40.0;
    let mut written = f64::NEG_INFINITY;
    loop {
        let now = gui.app().now_s();
        if now >= end {
            break;
        }
        let step = now.floor();
        if step > written {
            written = step;
            // Type K at 25 °C terminals: 5-15 mV is about 150-390 °C.
            let mv =
                if step < start { 12.2 } else { 10.0 + 5.0 * ((step - start) * std::f64::consts::TAU / 20.0).sin() };
            s8318.write(&format!(
                "cjc_celsius = 24.5\n[ch0]\nopen = true\n[ch1]\nmillivolts = 40.0\n[ch2]\nmillivolts = 1.0\n[ch3]\nmillivolts = {mv:.3}\n"
            ));
        }
        gui.frames(1);
        std::thread::sleep(Duration::from_millis(20));
    }
    gui.click("Pause");
    gui.frames(3);
    let points = &gui.app().trend.series[name];
    let span = points.back().map_or(0.0, |p| p[0]) - points.front().map_or(0.0, |p| p[0]);
    assert!(span >= 30.0, "the trend holds {span:.1} s");
    gui.harness.snapshot_options("trend", &options(20000));

    // What the trend shows, exported: a time column and the picked series, 30 s and more.
    let csv = temp("trend.csv");
    gui.set_text("CSV file", csv.to_str().expect("utf-8"));
    gui.click("Export CSV");
    gui.wait("written", |g| g.has_part("Trend written to"));
    let text = std::fs::read_to_string(&csv).expect("the CSV file");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(format!("time_s,\"{name}\"").as_str()));
    let times: Vec<f64> = lines.filter_map(|l| l.split(',').next()?.parse().ok()).collect();
    let (first, last) = (times.first().copied().unwrap_or(0.0), times.last().copied().unwrap_or(0.0));
    assert!(last - first >= 30.0 && times.len() >= 300, "{} rows over {:.1} s", times.len(), last - first);

    // The main window in Chinese (the CJK font of the system).
    gui.click("Network Settings");
    gui.click("中文");
    gui.frames(5);
    gui.harness.snapshot_options("main_window_zh", &options(1500));
}
