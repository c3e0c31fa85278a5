//! The 8318's resources of the web console's API on the host build (`--http`, docs/web.md):
//! channel values in engineering units that follow the input type, written through a signed
//! request and confirmed by Modbus.

use std::time::{Duration, Instant};

use remodaq_board_host::testing::web::{field, log_in, number, request};
use remodaq_board_host::testing::SimModule;
use remodaq_protocol::auth::FACTORY_PASSWORD;
use tokio_modbus::client::{tcp, Reader};

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8318");

/// GETs `target` until `done` holds for its body (10 s at most).
async fn get_until(web: std::net::SocketAddr, target: &str, done: impl Fn(&str) -> bool) -> String {
    let started = Instant::now();
    loop {
        let answer = request(web, "GET", target, &[], "");
        if done(&answer.body) {
            return answer.body;
        }
        assert!(started.elapsed() < Duration::from_secs(10), "{target}: {}", answer.body);
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn channel_values_follow_the_input_type() {
    let dir = remodaq_board_host::testing::temp("web-8318", "d");
    std::fs::create_dir_all(&dir).unwrap();
    let scenario = dir.join("scenario.toml");
    std::fs::write(
        &scenario,
        "cjc_celsius = 25.0\n[ch0]\nmillivolts = 41.276\n[ch1]\nvolts = 1.2\n[ch3]\nopen = true\n",
    )
    .unwrap();
    let flash = remodaq_board_host::testing::temp("web-8318", "web.flash");
    let args = ["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0", "--scenario", scenario.to_str().unwrap()];
    let module = SimModule::start_with(BIN, &flash, &args);
    let (web, modbus) = (module.web.expect("web address"), module.addr);
    let mut ctx = tcp::connect(modbus).await.expect("modbus");

    // Factory type K (0Fh, -250 .. 1400 °C). 41.276 mV with the cold junction at 25 °C: by the
    // NIST ITS-90 type K table E(25 °C) = 1.000 mV, 42.276 mV lies between E(1025 °C) = 42.247
    // and E(1026 °C) = 42.286 mV: 1025.74 °C (one count of the range is 0.025 °C).
    let inputs = request(web, "GET", "/api/v1/inputs", &[], "");
    assert!(
        inputs.body.contains(r#""type":{"code":15,"unit":"°C","lo":-250,"hi":1400,"thermocouple":"K"}"#),
        "{}",
        inputs.body
    );
    let ch = get_until(web, "/api/v1/channels", |b| b.contains("\"status\":\"open\"")).await;
    let first = ch.split("},{").next().unwrap_or("");
    let t = 1025.0 + (42.276 - 42.247) / (42.286 - 42.247);
    let value = number(first, "value").expect("a value");
    assert!((value - t).abs() <= 0.06, "channel 0 reads {value} °C, want {t:.2}: {ch}");
    assert_eq!(field(first, "status"), "ok");
    assert_eq!(ch.matches("\"enabled\":true").count(), 8, "{ch}");
    let inputs = request(web, "GET", "/api/v1/inputs", &[], "");
    assert!((number(&inputs.body, "cjc").expect("cjc") - 25.0).abs() < 0.01, "{}", inputs.body);

    // The open-input value (extensions §2, 00E8h): channel 3's thermocouple is open; upscale
    // (0, factory) reads FFFFh, downscale (1) reads 0000h. Written by name, read back by
    // Modbus, shown by name, and in force on the open channel.
    let mut page = log_in(web, FACTORY_PASSWORD).unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    assert!(inputs.body.contains(r#""open_value":"upscale""#), "{}", inputs.body);
    assert_eq!(ctx.read_holding_registers(0xE8, 1).await.unwrap().unwrap(), [0]);
    let ch3 = get_until(web, "/api/v1/channels/3", |b| b.contains("\"status\":\"open\"")).await;
    assert_eq!(number(&ch3, "raw"), Some(65535.0), "{ch3}");
    let body = r#"{"value":"downscale"}"#;
    let headers = page.sign("PUT", "/api/v1/inputs/open_value", body);
    assert_eq!(request(web, "PUT", "/api/v1/inputs/open_value", &headers, body).status, 204);
    assert_eq!(ctx.read_holding_registers(0xE8, 1).await.unwrap().unwrap(), [1]);
    let inputs = request(web, "GET", "/api/v1/inputs", &[], "");
    assert!(inputs.body.contains(r#""open_value":"downscale""#), "{}", inputs.body);
    let ch3 = get_until(web, "/api/v1/channels/3", |b| number(b, "raw") == Some(0.0)).await;
    assert_eq!(field(&ch3, "status"), "open", "{ch3}");

    // To ±2.5 V (05h) by a signed write: Modbus reads 05h at 40201, the unit becomes mV and
    // channel 1 reads 1.2 V = 1200 mV (one count: 0.076 mV).
    let body = r#"{"value":5}"#;
    let headers = page.sign("PUT", "/api/v1/inputs/type", body);
    assert_eq!(request(web, "PUT", "/api/v1/inputs/type", &headers, body).status, 204);
    assert_eq!(ctx.read_holding_registers(0xC8, 1).await.unwrap().unwrap(), [5]);
    let inputs = request(web, "GET", "/api/v1/inputs", &[], "");
    assert!(
        inputs.body.contains(r#""type":{"code":5,"unit":"mV","lo":-2500,"hi":2500,"thermocouple":""}"#),
        "{}",
        inputs.body
    );
    let one =
        get_until(web, "/api/v1/channels/1", |b| number(b, "value").is_some_and(|v| (v - 1200.0).abs() < 0.1)).await;
    assert_eq!(field(&one, "status"), "ok", "{one}");

    // The CJC offset in °C: +1.25 is 125 hundredths at 40216; +60 °C is refused (spec §2.4:
    // -50.00 .. +50.00), naming the field, with nothing changed.
    let body = r#"{"value":1.25}"#;
    let headers = page.sign("PUT", "/api/v1/inputs/cjc_offset", body);
    assert_eq!(request(web, "PUT", "/api/v1/inputs/cjc_offset", &headers, body).status, 204);
    assert_eq!(ctx.read_holding_registers(0xD7, 1).await.unwrap().unwrap(), [125]);
    let body = r#"{"value":60}"#;
    let headers = page.sign("PUT", "/api/v1/inputs/cjc_offset", body);
    let refused = request(web, "PUT", "/api/v1/inputs/cjc_offset", &headers, body);
    assert_eq!((refused.status, field(&refused.body, "field")), (422, "cjc_offset"), "{}", refused.body);
    assert_eq!(ctx.read_holding_registers(0xD7, 1).await.unwrap().unwrap(), [125]);
    // -2.00 °C: FF38h (two's complement within B000h..FFFFh, spec §2.4).
    let body = r#"{"value":-2}"#;
    let headers = page.sign("PUT", "/api/v1/inputs/cjc_offset", body);
    assert_eq!(request(web, "PUT", "/api/v1/inputs/cjc_offset", &headers, body).status, 204);
    assert_eq!(ctx.read_holding_registers(0xD7, 1).await.unwrap().unwrap(), [0xFF38]);
    assert!(request(web, "GET", "/api/v1/inputs", &[], "").body.contains("\"cjc_offset\":-2.00"));

    // The channel enable mask (40221, 00DCh: bit n = channel n, spec §2.1): channels 0 and 2
    // only (05h). Modbus reads it back; each channel shows its own bit, in order; a disabled
    // channel reads 0000h with the status "disabled" (spec §2.1, extensions §2).
    let body = r#"{"value":5}"#;
    let headers = page.sign("PUT", "/api/v1/inputs/enable_mask", body);
    assert_eq!(request(web, "PUT", "/api/v1/inputs/enable_mask", &headers, body).status, 204);
    assert_eq!(ctx.read_holding_registers(0xDC, 1).await.unwrap().unwrap(), [5]);
    assert_eq!(number(&request(web, "GET", "/api/v1/inputs", &[], "").body, "enable_mask"), Some(5.0));
    let ch = get_until(web, "/api/v1/channels", |b| b.matches("\"status\":\"disabled\"").count() == 6).await;
    let enabled: Vec<bool> = ch.split("\"enabled\":").skip(1).map(|r| r.starts_with("true")).collect();
    assert_eq!(enabled, [true, false, true, false, false, false, false, false], "{ch}");
    for (n, item) in ch.split("},{").enumerate() {
        let on = n == 0 || n == 2;
        assert_eq!(field(item, "status") == "disabled", !on, "channel {n}: {item}");
        if !on {
            assert_eq!(number(item, "raw"), Some(0.0), "channel {n}: {item}");
        }
    }
}
