//! MQTT on the simulated 8350 (`--mqtt`, docs/mqtt.md) against Debian's mosquitto started here:
//! a point changed over Modbus is published with the value a Modbus read of it gives, and a
//! command published to the module is applied and read back over Modbus, and after the broker
//! restarted the module is online again with its current values (issue #40).

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use remodaq_mqtt::testing::{free_port, publish, Broker, Subscriber};

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8350");
/// The module's MAC (`--mac`): its default prefix is `remodaq/8350/028350000001`.
const MAC: &str = "02:83:50:00:00:01";
const PREFIX: &str = "remodaq/8350/028350000001";

struct Module(Child);

impl Drop for Module {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// One Modbus/TCP request (MBAP + `pdu`) on a new connection; the answer's PDU.
fn modbus(port: u16, pdu: &[u8]) -> Vec<u8> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).expect("the module's Modbus port");
    s.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    let mut frame = vec![0, 1, 0, 0, 0, (pdu.len() + 1) as u8, 1];
    frame.extend_from_slice(pdu);
    s.write_all(&frame).expect("send");
    let mut head = [0u8; 7];
    s.read_exact(&mut head).expect("MBAP");
    let mut body = vec![0u8; usize::from(u16::from_be_bytes([head[4], head[5]])) - 1];
    s.read_exact(&mut body).expect("PDU");
    body
}

/// The payload's `"name":value` text (flat JSON, as the module publishes it).
fn field<'a>(payload: &'a str, name: &str) -> Option<&'a str> {
    let rest = payload.split(&format!("\"{name}\":")).nth(1)?;
    Some(rest.split([',', '}']).next().unwrap_or(""))
}

#[test]
fn published_values_are_modbus_reads_and_commands_apply() {
    let broker = Broker::start();
    let sub = Subscriber::with_args(broker.port, &["-t", "remodaq/#"]);
    let modbus_port = free_port();
    let flash = broker.dir.join("module.flash");
    let module = Module(
        Command::new(BIN)
            .args(["--listen", &format!("127.0.0.1:{modbus_port}"), "--mac", MAC])
            .arg("--flash")
            .arg(&flash)
            .args([
                "--discovery",
                &format!("127.0.0.1:{}", free_port()),
                "--mqtt",
                &format!("127.0.0.1:{}", broker.port),
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("the simulated 8350"),
    );
    let status = sub.next_on(&format!("{PREFIX}/status"), Duration::from_secs(15)).expect("online");
    assert!(status.1.contains("\"state\":\"online\"") && status.1.contains("\"model\":\"8350\""), "{status:?}");

    // DI5 to frequency mode over Modbus (spec §3.2: register 105h, value 4): published with
    // the mode a Modbus read gives.
    assert_eq!(modbus(modbus_port, &[0x06, 0x01, 0x05, 0x00, 0x04]), [0x06, 0x01, 0x05, 0x00, 0x04]);
    let read = modbus(modbus_port, &[0x03, 0x01, 0x05, 0x00, 0x01]);
    assert_eq!(read, [0x03, 0x02, 0x00, 0x04], "a Modbus read of DI5's mode");
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let (_, payload) = sub.next_on(&format!("{PREFIX}/di/5"), Duration::from_secs(5)).expect("DI5 published");
        if field(&payload, "mode") == Some("\"frequency\"") {
            break;
        }
        assert!(Instant::now() < deadline, "DI5's mode never published as Modbus reads it: {payload}");
    }

    // A command: DO3 on (normal mode), applied and read back over Modbus (spec §3.1: coil 13h),
    // and echoed on its point.
    publish(broker.port, &format!("{PREFIX}/do/3/set"), r#"{"level": true}"#);
    let deadline = Instant::now() + Duration::from_secs(5);
    while modbus(modbus_port, &[0x01, 0x00, 0x13, 0x00, 0x01]) != [0x01, 0x01, 0x01] {
        assert!(Instant::now() < deadline, "DO3 never on");
        std::thread::sleep(Duration::from_millis(50));
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let (_, payload) = sub.next_on(&format!("{PREFIX}/do/3"), Duration::from_secs(5)).expect("DO3 published");
        if field(&payload, "state") == Some("true") {
            break;
        }
        assert!(Instant::now() < deadline, "DO3's state never published on: {payload}");
    }

    // The diagnostics (docs/diagnostics.md, 40328-40333): connected, one session; then a
    // malformed command, an oversized one (refused, counted, DO2 unchanged) and one for an
    // output the module has not (ignored, counted).
    assert_eq!(
        mqtt_diagnostics(modbus_port)[..6],
        [2, 1, 0, 0, 0, 0],
        "state, sessions, failures, malformed, refused, ignored"
    );
    let oversized = format!(r#"{{"level": true, "pad": "{}"}}"#, "x".repeat(200));
    for (topic, payload) in
        [("do/2/set", r#"{"level": 1}"#), ("do/2/set", oversized.as_str()), ("do/9/set", r#"{"level": true}"#)]
    {
        publish(broker.port, &format!("{PREFIX}/{topic}"), payload);
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    while mqtt_diagnostics(modbus_port)[3..6] != [2, 0, 1] {
        assert!(Instant::now() < deadline, "the refusals counted: {:?}", mqtt_diagnostics(modbus_port));
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(modbus(modbus_port, &[0x01, 0x00, 0x12, 0x00, 0x01]), [0x01, 0x01, 0x00], "DO2 unchanged");

    // The broker restarted (down 2 s, nothing kept): the module connects again after its
    // back-off, says online again, and publishes its current values (DI5 in frequency mode,
    // DO3 on) to the new subscriber.
    let mut broker = broker;
    drop(sub);
    broker.restart(Duration::from_secs(2));
    let sub = Subscriber::with_args(broker.port, &["-t", "remodaq/#"]);
    let back = Instant::now();
    let status = sub.next_on(&format!("{PREFIX}/status"), Duration::from_secs(15)).expect("online again");
    assert!(status.1.contains("\"state\":\"online\""), "{status:?}");
    let di5 = sub.next_on(&format!("{PREFIX}/di/5"), Duration::from_secs(3)).expect("DI5 again").1;
    assert_eq!(field(&di5, "mode"), Some("\"frequency\""), "{di5}");
    let do3 = sub.next_on(&format!("{PREFIX}/do/3"), Duration::from_secs(3)).expect("DO3 again").1;
    assert_eq!(field(&do3, "state"), Some("true"), "{do3}");
    eprintln!("online again {:?} after the broker came back", back.elapsed());
    // A second session; the broken one (and any attempt while the broker was down) counted.
    let d = mqtt_diagnostics(modbus_port);
    assert!(d[0] == 2 && d[1] == 2 && d[2] >= 1, "state, sessions, failures: {d:?}");
    drop(module);
}

/// MQTT's diagnostics registers, 40328-40337 (PDU 0147h-0150h, docs/diagnostics.md): state,
/// sessions, failures, commands malformed, refused, ignored, TLS without a time, certificates
/// refused, handshakes failed, credentials refused without TLS.
fn mqtt_diagnostics(port: u16) -> [u16; 10] {
    let answer = modbus(port, &[0x03, 0x01, 0x47, 0x00, 0x0A]);
    assert_eq!(answer[..2], [0x03, 20], "{answer:02x?}");
    core::array::from_fn(|i| u16::from_be_bytes([answer[2 + 2 * i], answer[3 + 2 * i]]))
}

/// MQTT's settings set through the web console (`PUT /api/v1/mqtt`, docs/mqtt.md): refused
/// while the factory password is in force; once a password is set, stored and in force at once
/// (the module comes online under the prefix set), read back by `GET`, kept across a restart
/// (online again from the stored settings alone), and switched off at once (the broker gives
/// the module's will, `offline`).
#[test]
fn settings_set_through_the_web_console_are_stored_and_in_force_at_once() {
    use remodaq_board_host::testing::web::{log_in, request};
    use remodaq_board_host::testing::SimModule;

    let broker = Broker::start();
    let sub = Subscriber::with_args(broker.port, &["-t", "test/sim/#"]);
    let flash = broker.dir.join("settings.flash");
    let start = || SimModule::start_with(BIN, &flash, &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let module = start();
    let web = module.web.expect("the web console");
    let settings = |on: bool| {
        format!(
            r#"{{"on":{on},"broker":"127.0.0.1","host":"","port":{},"client_id":"","tls":false,"prefix":"test/sim",
            "period_ms":1000,"qos":1,"deadbands":[0,0,0,0,0,0,0,0],"on_change":true,"commands":false,"sntp":""}}"#,
            broker.port
        )
    };
    let put = |page: &mut remodaq_board_host::testing::web::Page, body: &str| {
        request(web, "PUT", "/api/v1/mqtt", &page.sign("PUT", "/api/v1/mqtt", body), body)
    };
    let mut page = log_in(web, "remodaq").unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    let on = settings(true);
    let refused = put(&mut page, &on);
    assert_eq!(refused.status, 403, "not with the factory password: {}", refused.body);
    assert_eq!(page.change_password(web, "plant password", [7; 16]).status, 204);
    let mut page = log_in(web, "plant password").unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    let stored = put(&mut page, &on);
    assert_eq!(stored.status, 204, "{}", stored.body);
    let online = sub.next_on("test/sim/status", Duration::from_secs(10)).expect("online at once");
    assert!(online.1.contains("\"state\":\"online\""), "{online:?}");
    let shown = request(web, "GET", "/api/v1/mqtt", &page.sign("GET", "/api/v1/mqtt", ""), "");
    assert_eq!(shown.status, 200);
    assert!(shown.body.contains(r#""on":true"#) && shown.body.contains(r#""prefix":"test/sim""#), "{}", shown.body);

    // Restarted on the same flash: online again from the stored settings alone.
    module.kill();
    let module = start();
    let deadline = Instant::now() + Duration::from_secs(15);
    loop {
        let (_, payload) = sub.next_on("test/sim/status", Duration::from_secs(15)).expect("a status");
        if payload.contains("\"state\":\"online\"") {
            break;
        }
        assert!(Instant::now() < deadline, "not online again after the restart");
    }
    // Off: the session ends at once, and the broker gives the will.
    let web = module.web.expect("the web console");
    let mut page = log_in(web, "plant password").unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    let off = settings(false);
    let stored = request(web, "PUT", "/api/v1/mqtt", &page.sign("PUT", "/api/v1/mqtt", &off), &off);
    assert_eq!(stored.status, 204, "{}", stored.body);
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let (_, payload) = sub.next_on("test/sim/status", Duration::from_secs(10)).expect("offline");
        if payload.contains("\"state\":\"offline\"") {
            break;
        }
        assert!(Instant::now() < deadline, "still online after MQTT was switched off");
    }
}

/// MQTT over TLS with the settings stored through the web console (issue #40): a broker with
/// only a TLS listener, a password file and an ACL (its certificates made here by openssl). TLS
/// without a CA stored: not connecting (40328 = 3). Another CA, then another host name: refused,
/// counted (40335). The right CA and name without credentials: the broker refuses the session
/// (40330). With the credentials (sealed on the wire): online, values published over TLS. TLS off
/// with the credentials stored: not connecting, counted (40337). The whole link captured by
/// tcpdump (where it runs): TLS records, and neither the password nor a topic in clear.
#[test]
fn over_tls_with_stored_settings() {
    use remodaq_board_host::testing::web::{log_in, request, Page};
    use remodaq_board_host::testing::SimModule;
    use remodaq_mqtt::testing::{make_pki, HOST, PASSWORD, USER};

    let broker = Broker::with(|port, dir| {
        make_pki(dir);
        std::fs::write(dir.join("acl"), format!("user {USER}\ntopic readwrite test/tls/#\n")).expect("acl");
        let d = dir.display();
        format!(
            "listener {port} 127.0.0.1\ncafile {d}/ca.pem\ncertfile {d}/server.pem\nkeyfile {d}/server.key\n\
             allow_anonymous false\npassword_file {d}/passwords\nacl_file {d}/acl\n"
        )
    });
    let capture = Capture::start(broker.port, &broker.dir.join("link.pcap"));
    let flash = broker.dir.join("module.flash");
    let module = SimModule::start_with(BIN, &flash, &["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"]);
    let (web, modbus_port) = (module.web.expect("the web console"), module.addr.port());
    let mut page = log_in(web, "remodaq").unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    assert_eq!(page.change_password(web, "plant password", [9; 16]).status, 204);
    let mut page = log_in(web, "plant password").unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    let put = |page: &mut Page, target: &str, body: &str| {
        let answer = request(web, "PUT", target, &page.sign("PUT", target, body), body);
        assert_eq!(answer.status, 204, "{target}: {}", answer.body);
    };
    let settings = |tls: bool, host: &str| {
        format!(
            r#"{{"on":true,"broker":"127.0.0.1","host":"{host}","port":{},"client_id":"","tls":{tls},"prefix":"test/tls",
            "period_ms":1000,"qos":1,"deadbands":[0,0,0,0,0,0,0,0],"on_change":true,"commands":false,"sntp":""}}"#,
            broker.port
        )
    };
    let pem = |name: &str| {
        let text = std::fs::read_to_string(broker.dir.join(name)).expect("a PEM");
        format!(r#"{{"pem":"{}"}}"#, text.trim().replace('\n', " "))
    };
    let until = |what: &str, ok: &dyn Fn(&[u16; 10]) -> bool| {
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            let d = mqtt_diagnostics(modbus_port);
            if ok(&d) {
                return d;
            }
            assert!(Instant::now() < deadline, "{what}: diagnostics {d:?}");
            std::thread::sleep(Duration::from_millis(100));
        }
    };

    put(&mut page, "/api/v1/mqtt", &settings(true, HOST));
    until("TLS without a CA: not usable", &|d| d[0] == 3);
    let not_json = request(
        web,
        "PUT",
        "/api/v1/mqtt/ca",
        &page.sign("PUT", "/api/v1/mqtt/ca", r#"{"pem":"x"}"#),
        r#"{"pem":"x"}"#,
    );
    assert_eq!(not_json.status, 422, "{}", not_json.body);
    // A CA the module's TLS cannot take is refused when it is installed, with why: RSA ones
    // (made here by openssl: of 2048 bits, larger than the record; of 1024, read and refused),
    // and a P-256 private key where the certificate belongs.
    for bits in [2048, 1024] {
        let made = std::process::Command::new("openssl")
            .args(["req", "-x509", "-newkey", &format!("rsa:{bits}"), "-nodes", "-subj", "/CN=rsa ca", "-days", "2"])
            .args(["-keyout", &format!("rsa{bits}.key"), "-out", &format!("rsa{bits}.pem")])
            .current_dir(&broker.dir)
            .output()
            .expect("openssl");
        assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    }
    let key_as_certificate = std::fs::read_to_string(broker.dir.join("ca.key"))
        .expect("the CA's key")
        .replace("EC PRIVATE KEY", "CERTIFICATE");
    std::fs::write(broker.dir.join("key.pem"), key_as_certificate).expect("written");
    for (file, why) in [
        ("rsa2048.pem", "an RSA one is larger"),
        ("rsa1024.pem", "not ECDSA P-256 with SHA-256"),
        ("key.pem", "not a certificate this module reads"),
    ] {
        let body = pem(file);
        let refused = request(web, "PUT", "/api/v1/mqtt/ca", &page.sign("PUT", "/api/v1/mqtt/ca", &body), &body);
        assert_eq!(refused.status, 422, "{file}: {}", refused.body);
        assert!(refused.body.contains(why) && refused.body.contains(r#""pem""#), "{file}: {}", refused.body);
    }
    put(&mut page, "/api/v1/mqtt/ca", &pem("other.pem"));
    until("another CA: the certificate refused", &|d| d[7] >= 1);
    put(&mut page, "/api/v1/mqtt/ca", &pem("ca.pem"));
    put(&mut page, "/api/v1/mqtt", &settings(true, "other.test"));
    let before = mqtt_diagnostics(modbus_port)[7];
    until("another host name: the certificate refused", &|d| d[7] > before);
    put(&mut page, "/api/v1/mqtt", &settings(true, HOST));
    let before = mqtt_diagnostics(modbus_port)[2];
    until("no credentials: the broker refuses the session", &|d| d[2] > before && d[1] == 0);
    let shown = request(web, "GET", "/api/v1/mqtt", &page.sign("GET", "/api/v1/mqtt", ""), "");
    assert!(shown.body.contains(r#""ca":true,"credentials":false"#), "{}", shown.body);

    let sub = Subscriber::with_args(
        broker.port,
        &[
            "--cafile",
            &broker.dir.join("ca.pem").display().to_string(),
            "--insecure",
            "-u",
            USER,
            "-P",
            PASSWORD,
            "-t",
            "test/tls/#",
        ],
    );
    let sealed = page.put_mqtt_credentials(web, USER, PASSWORD);
    assert_eq!(sealed.status, 204, "{}", sealed.body);
    let online = sub.next_on("test/tls/status", Duration::from_secs(20)).expect("online over TLS");
    assert!(online.1.contains(r#""state":"online""#), "{online:?}");
    assert!(sub.next_on("test/tls/di/0", Duration::from_secs(5)).is_some(), "a value over TLS");
    // The first look's last point too, before the settings change below ends the session: the
    // capture then holds every point's record (the count checked below), however fast this
    // test goes on.
    assert!(sub.next_on("test/tls/do/5", Duration::from_secs(5)).is_some(), "every point over TLS");
    assert_eq!(mqtt_diagnostics(modbus_port)[..2], [2, 1], "connected, one session");
    let shown = request(web, "GET", "/api/v1/mqtt", &page.sign("GET", "/api/v1/mqtt", ""), "");
    assert!(shown.body.contains(r#""credentials":true"#) && !shown.body.contains(PASSWORD), "{}", shown.body);

    put(&mut page, "/api/v1/mqtt", &settings(false, HOST));
    until("credentials without TLS: refused, counted", &|d| d[0] == 3 && d[9] == 1);
    // Another broker's name with TLS (or another CA): the credentials stay home (they were
    // stored for broker.test), counted.
    put(&mut page, "/api/v1/mqtt", &settings(true, "other.test"));
    until("credentials stored for another broker: refused, counted", &|d| d[0] == 3 && d[9] == 2);
    put(&mut page, "/api/v1/mqtt", &settings(true, HOST));
    until("the broker they were stored for again: online", &|d| d[0] == 2);
    drop(module);
    drop(sub);

    match capture.finish() {
        Some(link) => {
            let tls_records = link.windows(3).filter(|w| *w == [0x17, 0x03, 0x03]).count();
            eprintln!("capture: {} bytes of the broker's port, {tls_records} TLS application records", link.len());
            // After the handshake every byte is application data: the module's CONNECT, its
            // status and points, the broker's CONNACK and acknowledgments. How many records
            // they make depends on how the writes were batched (5 to 166 seen for the same
            // session): at least the four kinds, whatever the batching.
            assert!(tls_records >= 4, "TLS application data in the capture");
            for secret in [PASSWORD.as_bytes(), b"test/tls/status", b"online"] {
                assert!(
                    !link.windows(secret.len()).any(|w| w == secret),
                    "{:?} in clear in the capture",
                    String::from_utf8_lossy(secret)
                );
            }
        }
        None => eprintln!("capture: not applicable here (tcpdump could not capture on lo)"),
    }
}

/// tcpdump on the loopback interface, the broker's port only, into `file`.
struct Capture {
    child: Option<Child>,
    file: std::path::PathBuf,
}

impl Capture {
    fn start(port: u16, file: &std::path::Path) -> Self {
        let child = Command::new("tcpdump")
            .args(["-i", "lo", "-U", "-s", "0", "-w"])
            .arg(file)
            .args(["tcp", "port", &port.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .ok();
        // tcpdump listens once it has opened the interface.
        std::thread::sleep(Duration::from_millis(700));
        Self { child, file: file.to_path_buf() }
    }

    /// The capture file's bytes, or `None` if tcpdump did not run (no permission).
    fn finish(mut self) -> Option<Vec<u8>> {
        let mut child = self.child.take()?;
        std::thread::sleep(Duration::from_millis(300));
        // SIGINT: tcpdump writes what it holds and exits.
        let _ = Command::new("kill").args(["-INT", &child.id().to_string()]).status();
        let _ = child.wait();
        let bytes = std::fs::read(&self.file).ok().filter(|b| b.len() > 24)?;
        let kept = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("mqtt-tls-link.pcap");
        let _ = std::fs::copy(&self.file, &kept);
        eprintln!("capture: kept in {}", kept.display());
        Some(bytes)
    }
}
