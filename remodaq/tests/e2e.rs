//! End to end: the `remodaq` tool against the host builds of both modules, on loopback.
//! (Search aims at each module's unicast discovery address instead of the broadcast address.)

use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use remodaq_board_host::testing::{program, SimModule};
use serde_json::Value;

mod common;

/// A firmware's host build, next to the tool's binary (`cargo test --workspace` builds it).
fn firmware(model: &str) -> String {
    let beside = PathBuf::from(env!("CARGO_BIN_EXE_remodaq")).with_file_name(format!("firmware-{model}"));
    let path = program(&format!("firmware-{model}"), &beside);
    assert!(path.exists(), "{} is missing: run the workspace's tests (cargo test --workspace)", path.display());
    path.to_string_lossy().into_owned()
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("remodaq-e2e-tool-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    let _ = std::fs::remove_file(&path);
    path
}

/// Runs the tool: exit code, stdout, stderr.
fn remodaq(args: &[&str]) -> (i32, String, String) {
    common::remodaq(args, &[])
}

fn json(args: &[&str]) -> Value {
    let mut all = vec!["--json"];
    all.extend_from_slice(args);
    let (code, out, err) = remodaq(&all);
    assert_eq!(code, 0, "{err}");
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("not JSON ({e}): {out}"))
}

fn search(module: &SimModule) -> Value {
    let found = json(&["--timeout", "1", "search", "--to", &module.discovery.to_string()]);
    assert_eq!(found.as_array().map(Vec::len), Some(1), "{found}");
    found[0].clone()
}

/// Reads (JSON) until `ok` accepts the reading, at most 5 s.
fn read_until(addr: &str, ok: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let r = json(&["read", addr]);
        if ok(&r) {
            return r;
        }
        assert!(Instant::now() < deadline, "reading never matched: {r}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

#[test]
fn search_finds_both_modules() {
    let m8318 = SimModule::start(&firmware("8318"), &temp("search-8318.flash"));
    let m8350 = SimModule::start(&firmware("8350"), &temp("search-8350.flash"));
    let a = search(&m8318);
    let b = search(&m8350);
    assert_eq!((a["model"].as_str(), b["model"].as_str()), (Some("8318"), Some("8350")));
    assert_eq!(a["running"]["port"].as_u64(), Some(u64::from(m8318.addr.port())));
    assert_eq!(a["firmware"].as_str(), Some("A100"));
    assert_ne!(a["mac"], b["mac"]);
    let (code, table, _) = remodaq(&["--timeout", "1", "search", "--to", &m8350.discovery.to_string()]);
    assert_eq!(code, 0);
    assert!(table.contains("RemoDAQ-8350") && table.contains(b["mac"].as_str().unwrap()), "{table}");
}

/// `remodaq net set` with every field: the factory values, then `changes` over them.
fn net_set(mac: &str, to: &str, password: &str, changes: &[(&str, &str)]) -> (i32, String, String) {
    let mut fields =
        vec![("--ip", "192.168.0.1"), ("--mask", "255.255.255.0"), ("--gateway", "0.0.0.0"), ("--port", "8000")];
    for (flag, value) in changes {
        if let Some(field) = fields.iter_mut().find(|(f, _)| f == flag) {
            field.1 = value;
        }
    }
    let mut args = vec!["net", "set", "--mac", mac, "--to", to, "--password", password];
    for (flag, value) in &fields {
        args.extend([*flag, *value]);
    }
    remodaq(&args)
}

#[test]
fn network_settings_password_and_restart() {
    let flash = temp("net.flash");
    let p1 = free_port();
    // Seed the stored port with a module on an ephemeral port.
    let seed = SimModule::start(&firmware("8318"), &flash);
    let mac = search(&seed)["mac"].as_str().unwrap().to_string();
    let to = seed.discovery.to_string();
    let (code, _, err) = net_set(&mac, &to, "wrong", &[("--port", &p1.to_string())]);
    assert_eq!(code, 5, "wrong password");
    assert!(err.contains("wrong password"), "{err}");
    assert_eq!(search(&seed)["stored"]["port"].as_u64(), Some(8000), "nothing changed");
    // The failure is a security event the diagnostics registers show.
    let security = json(&["read", &seed.addr.to_string()])["diagnostics"]["security"].clone();
    assert_eq!(security["auth_failures"].as_u64(), Some(1), "{security}");
    assert_eq!(security["last_failed_source"].as_str(), Some("127.0.0.1"), "{security}");
    assert_eq!(security["factory_password"].as_bool(), Some(true), "{security}");
    let (code, out, _) = net_set(&mac, &to, "remodaq", &[("--port", &p1.to_string())]);
    assert_eq!(code, 0);
    assert!(out.contains("stored"), "{out}");
    assert!(out.contains("factory password"), "the tool says the factory password is in force: {out}");
    assert_eq!(search(&seed)["stored"]["port"].as_u64(), Some(u64::from(p1)));
    seed.kill();

    // Listening on the settings' port: the stored port is in force after a start.
    let mut module = SimModule::start_with(&firmware("8318"), &flash, &["--listen", "127.0.0.1"]);
    assert_eq!(module.addr.port(), p1);
    let to = module.discovery.to_string();
    // A new port, address, mask and gateway, and a restart: the restart applies them. (The
    // simulated module listens where `--listen` says; it shows and keeps the stored address.)
    let p2 = free_port();
    let p2s = p2.to_string();
    let changes =
        [("--port", p2s.as_str()), ("--ip", "10.0.0.50"), ("--mask", "255.255.0.0"), ("--gateway", "10.0.0.1")];
    let (code, _, _) = net_set(&mac, &to, "remodaq", &changes);
    assert_eq!(code, 0);
    let (code, out, _) = remodaq(&["restart", "--mac", &mac, "--to", &to, "--password", "remodaq"]);
    assert_eq!(code, 0, "{out}");
    module.wait_listening();
    assert_eq!(module.addr.port(), p2, "the restarted module listens on the new port");
    let running = search(&module);
    assert_eq!(running["running"]["port"].as_u64(), Some(u64::from(p2)));
    let stored = &running["stored"];
    assert_eq!(
        (stored["ip"].as_str(), stored["mask"].as_str(), stored["gateway"].as_str(), stored["port"].as_u64()),
        (Some("10.0.0.50"), Some("255.255.0.0"), Some("10.0.0.1"), Some(u64::from(p2))),
        "{running}"
    );
    assert_eq!(running["running"]["ip"].as_str(), Some("127.0.0.1"));
    let read = json(&["read", &module.addr.to_string()]);
    assert_eq!(read["model"].as_str(), Some("RemoDAQ-8318"));
    assert_eq!(read["diagnostics"]["reset_cause"].as_str(), Some("software restart"), "{read}");

    // Identify; a password change; a MAC that is not there.
    let to = module.discovery.to_string();
    assert_eq!(remodaq(&["identify", "--mac", &mac, "--to", &to]).0, 0);
    let short = remodaq(&["password", "--mac", &mac, "--to", &to, "--password", "remodaq", "--new", "short"]);
    assert_eq!(short.0, 1, "at least 8 characters: {}", short.2);
    assert_eq!(search(&module)["factory_password"].as_bool(), Some(true));
    assert_eq!(
        remodaq(&["password", "--mac", &mac, "--to", &to, "--password", "remodaq", "--new", "line 4 secret"]).0,
        0
    );
    assert_eq!(search(&module)["factory_password"].as_bool(), Some(false));
    assert_eq!(remodaq(&["restart", "--mac", &mac, "--to", &to, "--password", "remodaq"]).0, 5);
    // The new password is in the settings: it is the one after a restart too.
    assert_eq!(remodaq(&["restart", "--mac", &mac, "--to", &to, "--password", "line 4 secret"]).0, 0);
    module.wait_listening();
    let to = module.discovery.to_string();
    assert_eq!(search(&module)["factory_password"].as_bool(), Some(false), "after the restart");
    let shown = remodaq(&["access", "show", "--mac", &mac, "--to", &to, "--password", "line 4 secret"]);
    assert_eq!(shown.0, 0, "the new password after a restart: {}", shown.2);
    let (code, _, err) = remodaq(&["--timeout", "0.5", "identify", "--mac", "02:00:00:00:00:01", "--to", &to]);
    assert_eq!(code, 3, "no module with that MAC");
    assert!(err.contains("timeout"), "{err}");
}

#[test]
fn read_and_config_round_trip_8318() {
    let module = SimModule::start(&firmware("8318"), &temp("io-8318.flash"));
    let addr = module.addr.to_string();
    assert_eq!(remodaq(&["config", &addr, "type", "J"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "enable", "0x0F"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "cjc-offset", "-2.5"]).0, 0);
    // Values follow at the next 100 ms acquisition cycle.
    let r = read_until(&addr, |r| r["cold_junction_c"].as_f64() == Some(22.5));
    assert_eq!(
        (r["type_code"].as_str(), r["input_type"].as_str(), r["unit"].as_str()),
        (Some("0E"), Some("thermocouple J"), Some("°C"))
    );
    assert_eq!(r["cjc_offset_c"].as_f64(), Some(-2.5));
    let channels = r["channels"].as_array().unwrap();
    assert_eq!(channels[7]["status"].as_str(), Some("disabled"));
    // 0 mV at the terminals reads the cold junction: 25 - 2.5 °C (within one step).
    let t = channels[0]["value"].as_f64().unwrap_or(f64::NAN);
    assert!((t - 22.5).abs() < 0.05, "{t}");
    assert_eq!(remodaq(&["config", &addr, "type", "05"]).0, 0);
    let r = read_until(&addr, |r| r["channels"][0]["value"].as_f64() == Some(0.0));
    assert_eq!((r["unit"].as_str(), r["channels"][0]["value"].as_f64()), (Some("V"), Some(0.0)));
    // Errors: a setting of the other model; an exception from the module, with its meaning.
    let (code, _, err) = remodaq(&["config", &addr, "di-mode", "0", "counter"]);
    assert_eq!(code, 1);
    assert!(err.contains("RemoDAQ-8350"), "{err}");
    let (code, _, err) = remodaq(&["config", &addr, "register", "40213", "0xA200"]);
    assert_eq!(code, 4);
    assert!(err.contains("02 illegal data address"), "{err}");
    let (code, _, err) = remodaq(&["--timeout", "1", "read", "127.0.0.1:1"]);
    assert_eq!(code, 1, "nothing listens on port 1");
    assert!(err.contains("cannot connect"), "{err}");
}

#[test]
fn read_watch_and_config_round_trip_8350() {
    let scenario = temp("scenario.toml");
    std::fs::write(&scenario, "[di0]\nsquare_hz = 50.0\n[di3]\nlevel = true\n").unwrap();
    let module = SimModule::start_with(
        &firmware("8350"),
        &temp("io-8350.flash"),
        &["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()],
    );
    let addr: SocketAddr = module.addr;
    let addr = addr.to_string();
    // DI0 counts its 50 Hz square wave from the mode write until the stop: the writes took
    // effect between their sending and their answers, so the count lies within 50 per second
    // of those bounds (±1 for the phase of the wave).
    let started = std::time::Instant::now();
    assert_eq!(remodaq(&["config", &addr, "di-mode", "0", "counter"]).0, 0);
    let counting = started.elapsed();
    assert_eq!(remodaq(&["config", &addr, "di-mode", "1", "latch-rising"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "do-mode", "2", "pulse"]).0, 0);
    assert_eq!(
        remodaq(&["config", &addr, "pulse", "2", "--low-ms", "1.5", "--high-ms", "0.5", "--count", "1000000"]).0,
        0
    );
    assert_eq!(remodaq(&["config", &addr, "do", "2", "on"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "do", "4", "on"]).0, 0);
    std::thread::sleep(Duration::from_millis(300));
    let stopping = started.elapsed();
    assert_eq!(remodaq(&["config", &addr, "counter", "0", "stop"]).0, 0);
    let stopped = started.elapsed();
    let r = json(&["read", &addr]);
    let (inputs, outputs) = (r["inputs"].as_array().unwrap(), r["outputs"].as_array().unwrap());
    assert_eq!(inputs[0]["mode"].as_str(), Some("counter"));
    let count = inputs[0]["value"].as_u64().unwrap() as f64;
    let (fewest, most) = (50.0 * (stopping - counting).as_secs_f64() - 1.0, 50.0 * stopped.as_secs_f64() + 1.0);
    assert!(
        (fewest.floor()..=most.ceil()).contains(&count),
        "DI0 counted {count} edges of 50 Hz, expected {fewest:.1}..{most:.1}"
    );
    let again = json(&["read", &addr])["inputs"][0]["value"].as_u64().unwrap() as f64;
    assert_eq!(again, count, "a stopped counter holds its value");
    assert_eq!((inputs[1]["mode"].as_str(), inputs[3]["state"].as_bool()), (Some("latch-rising"), Some(true)));
    assert_eq!(outputs[2]["mode"].as_str(), Some("pulse"));
    assert_eq!(
        (outputs[2]["low_ms"].as_f64(), outputs[2]["high_ms"].as_f64(), outputs[2]["count"].as_u64()),
        (Some(1.5), Some(0.5), Some(1_000_000))
    );
    assert_eq!((outputs[2]["state"].as_bool(), outputs[4]["state"].as_bool()), (Some(true), Some(true)));
    assert_eq!(remodaq(&["config", &addr, "counter", "0", "stop"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "counter", "0", "clear"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "do", "2", "off"]).0, 0);
    let r = json(&["read", &addr]);
    assert_eq!((r["inputs"][0]["value"].as_u64(), r["inputs"][0]["counter_running"].as_bool()), (Some(0), Some(false)));
    assert_eq!(r["outputs"][2]["state"].as_bool(), Some(false));
    // watch: one JSON object per line.
    let (code, out, _) = remodaq(&["--json", "watch", &addr, "--interval", "0.1", "--count", "3"]);
    assert_eq!(code, 0);
    let lines: Vec<Value> = out.lines().map(|l| serde_json::from_str(l).expect("JSON line")).collect();
    assert_eq!(lines.len(), 3);
    assert!(lines.iter().all(|l| l["model"].as_str() == Some("RemoDAQ-8350")));
    let (code, out, _) = remodaq(&["read", &addr]);
    assert_eq!(code, 0);
    assert!(out.contains("DI3") && out.contains("latch-rising"), "{out}");
}

#[test]
fn watchdog_safe_state_and_access_through_the_tool() {
    let module = SimModule::start(&firmware("8350"), &temp("ext-8350.flash"));
    let (addr, to) = (module.addr.to_string(), module.discovery.to_string());
    let mac = search(&module)["mac"].as_str().unwrap().to_string();
    let read = || json(&["read", &addr, "--discovery", &to]);
    assert_eq!(remodaq(&["config", &addr, "safe", "0b000101"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "power-on", "0b10"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "watchdog", "0.5", "--writes-only"]).0, 0);
    let r = read();
    assert_eq!(r["writes_restricted"].as_bool(), Some(false), "{r}");
    assert_eq!((r["watchdog"]["timeout_s"].as_f64(), r["watchdog"]["writes_only"].as_bool()), (Some(0.5), Some(true)));
    std::thread::sleep(Duration::from_millis(900));
    let r = read();
    assert_eq!(r["watchdog"]["tripped"].as_bool(), Some(true), "{r}");
    let states: Vec<bool> = r["outputs"].as_array().unwrap().iter().map(|o| o["state"].as_bool().unwrap()).collect();
    assert_eq!(states, [true, false, true, false, false, false], "the safe levels");
    let (code, _, err) = remodaq(&["config", &addr, "do", "1", "on"]);
    assert_eq!(code, 4, "{err}");
    assert!(err.contains("04") && err.contains("safe state"), "{err}");
    let (_, out, _) = remodaq(&["read", &addr, "--discovery", &to]);
    assert!(out.contains("TRIPPED"), "{out}");
    assert_eq!(remodaq(&["config", &addr, "watchdog", "clear"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "watchdog", "off"]).0, 0);
    assert_eq!(read()["watchdog"]["tripped"].as_bool(), Some(false));

    // The allow-list: only 127.0.0.2 may write; this PC (127.0.0.1) gets exception 01. Not
    // while the factory password is in force: a password first.
    let factory = ["--mac", &mac, "--to", &to, "--password", "remodaq"];
    let refused = remodaq(&[&["access", "set"][..], &factory, &["127.0.0.2/32"]].concat());
    assert_eq!(refused.0, 5, "{}", refused.2);
    assert!(refused.2.contains("set a password first"), "{}", refused.2);
    assert_eq!(remodaq(&[&["password", "--new", "plant password"][..], &factory].concat()).0, 0);
    let target = ["--mac", &mac, "--to", &to, "--password", "plant password"];
    let set = [&["access", "set"][..], &target, &["127.0.0.2/32", "10.1.0.0/16"]].concat();
    assert_eq!(remodaq(&set).0, 0);
    let shown = json(&[&["access", "show"][..], &target].concat());
    assert_eq!(shown["allow"], serde_json::json!(["127.0.0.2/32", "10.1.0.0/16"]), "{shown}");
    let (code, _, err) = remodaq(&["config", &addr, "do", "1", "on"]);
    assert_eq!(code, 4, "{err}");
    assert!(err.contains("01"), "{err}");
    assert_eq!(read()["writes_restricted"].as_bool(), Some(true));
    let (_, out, _) = remodaq(&["read", &addr, "--discovery", &to]);
    assert!(out.contains("writes: restricted"), "{out}");
    let wrong = ["access", "show", "--mac", &mac, "--to", &to, "--password", "nope"];
    assert_eq!(remodaq(&wrong).0, 5, "the list needs the password");
    assert_eq!(remodaq(&[&["access", "clear"][..], &target].concat()).0, 0);
    assert_eq!(remodaq(&["config", &addr, "do", "1", "on"]).0, 0, "writes allowed again");
}

#[test]
fn channel_status_and_open_value_through_the_tool() {
    let scenario = temp("status.toml");
    std::fs::write(&scenario, "[ch0]\nopen = true\n[ch1]\nmillivolts = 60.0\n").unwrap();
    let module = SimModule::start_with(
        &firmware("8318"),
        &temp("status-8318.flash"),
        &["--listen", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()],
    );
    let addr = module.addr.to_string();
    assert_eq!(remodaq(&["config", &addr, "enable", "0x7F"]).0, 0);
    assert_eq!(remodaq(&["config", &addr, "open-value", "downscale"]).0, 0);
    let r = read_until(&addr, |r| r["channels"][0]["status"].as_str() == Some("open"));
    let status: Vec<&str> = r["channels"].as_array().unwrap().iter().map(|c| c["status"].as_str().unwrap()).collect();
    assert_eq!(status[..3], ["open", "over range", "ok"], "{r}");
    assert_eq!(status[7], "disabled");
    assert_eq!(r["open_value"].as_str(), Some("downscale"));
}

/// MQTT's settings through the tool (`remodaq mqtt`, docs/mqtt.md), by the module's web console
/// after a login: shown; not changed while the factory password is in force, nor with a wrong
/// password; once a password is set, only the settings given change, and a value out of range
/// is refused with the field named.
#[test]
fn mqtt_settings_through_the_tool() {
    let flash = temp("mqtt.flash");
    let module =
        SimModule::start_with(&firmware("8350"), &flash, &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let web = module.web.expect("the web console").to_string();
    let shown = json(&["mqtt", "show", &web, "--password", "remodaq"]);
    assert_eq!(
        (shown["on"].as_bool(), shown["port"].as_u64(), shown["tls"].as_bool()),
        (Some(false), Some(8883), Some(true)),
        "{shown}"
    );
    let set =
        ["mqtt", "set", &web, "--on", "--broker", "192.0.2.50", "--port", "1883", "--tls", "off", "--deadband", "7=50"];
    let (code, _, err) = remodaq(&[&set[..], &["--password", "remodaq"]].concat());
    assert_ne!(code, 0);
    assert!(err.contains("set a password first"), "{err}");
    let (code, _, err) = remodaq(&[&set[..], &["--password", "not the password"]].concat());
    assert_eq!(code, 5, "{err}");
    let mac = search(&module)["mac"].as_str().expect("the MAC").to_owned();
    let to = module.discovery.to_string();
    let changed = remodaq(&["password", "--mac", &mac, "--to", &to, "--password", "remodaq", "--new", "line 2 secret"]);
    assert_eq!(changed.0, 0, "{}", changed.2);
    let after = json(&[&set[..], &["--password", "line 2 secret"]].concat());
    assert_eq!(
        (after["on"].as_bool(), after["broker"].as_str(), after["port"].as_u64(), after["tls"].as_bool()),
        (Some(true), Some("192.0.2.50"), Some(1883), Some(false)),
        "{after}"
    );
    assert_eq!(after["deadbands"][7].as_u64(), Some(50), "{after}");
    assert_eq!(after["period_ms"].as_u64(), Some(10_000), "not given: kept ({after})");
    let (code, _, err) = remodaq(&["mqtt", "set", &web, "--qos", "2", "--password", "line 2 secret"]);
    assert_eq!(code, 1);
    assert!(err.contains("qos"), "{err}");
    // A DER file that is no certificate (30 03 02 01 01, a SEQUENCE): the module refuses it, and
    // the tool says why.
    let junk = temp("mqtt-junk.der");
    std::fs::write(&junk, [0x30, 3, 2, 1, 1]).expect("write");
    let junk_arg = junk.display().to_string();
    let (code, _, err) = remodaq(&["mqtt", "set", &web, "--ca", &junk_arg, "--password", "line 2 secret"]);
    assert_eq!(code, 1);
    assert!(err.contains("not a certificate this module reads"), "{err}");
    // The CA (a P-256 one made by openssl, as DER) and the broker's credentials (the password
    // from REMODAQ_MQTT_PASSWORD): stored, never shown.
    let ca = temp("mqtt-ca.der");
    let key = temp("mqtt-ca.key");
    let openssl = |args: &[&str]| {
        let made = std::process::Command::new("openssl").args(args).output().expect("openssl");
        assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    };
    openssl(&["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", &key.display().to_string()]);
    openssl(&[
        "req",
        "-x509",
        "-key",
        &key.display().to_string(),
        "-subj",
        "/CN=test ca",
        "-days",
        "2",
        "-outform",
        "DER",
        "-out",
        &ca.display().to_string(),
    ]);
    let ca_arg = ca.display().to_string();
    let tls = ["mqtt", "set", &web, "--tls", "on", "--host", "broker.test", "--ca", &ca_arg, "--user", "plant"];
    let (code, out, err) = common::remodaq(
        &[&tls[..], &["--password", "line 2 secret", "--json"]].concat(),
        &[("REMODAQ_MQTT_PASSWORD", "broker pass 7")],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.contains(r#""ca":true"#) && out.contains(r#""credentials":true"#), "{out}");
    assert!(!out.contains("broker pass 7") && !err.contains("broker pass 7"), "{out} {err}");
}
