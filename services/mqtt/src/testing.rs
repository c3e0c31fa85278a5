//! What the tests against mosquitto share (feature `testing`, the tests' only): Debian's
//! mosquitto on a port of its own, and a subscriber (`mosquitto_sub`).

use std::format;
use std::io::{BufRead, BufReader};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Command as Process, Stdio};
use std::string::{String, ToString};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};
use std::vec::Vec;

/// A free TCP port of the loopback.
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("a free port").local_addr().expect("its address").port()
}

/// mosquitto on a port of its own, killed when dropped.
pub struct Broker {
    child: Child,
    /// Its port on 127.0.0.1.
    pub port: u16,
    /// Its directory (configuration, log, the tests' files), removed with it.
    pub dir: std::path::PathBuf,
}

impl Broker {
    /// An anonymous broker.
    pub fn start() -> Self {
        Self::with(|port, _| format!("listener {port} 127.0.0.1\nallow_anonymous true\n"))
    }

    /// A broker whose configuration `conf(port, dir)` gives (logging and persistence are added).
    pub fn with(conf: impl FnOnce(u16, &std::path::Path) -> String) -> Self {
        let port = free_port();
        let dir = std::env::temp_dir().join(format!("rdaq-mqtt-{}-{port}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a directory");
        let text = format!("{}persistence false\nlog_type all\nlog_dest stdout\n", conf(port, &dir));
        std::fs::write(dir.join("mosquitto.conf"), text).expect("the configuration");
        let child = Self::run(port, &dir);
        Self { child, port, dir }
    }

    /// mosquitto on `port` with the configuration in `dir`, once it listens.
    fn run(port: u16, dir: &std::path::Path) -> Child {
        // Debian puts the broker in /usr/sbin, which a user's PATH may lack.
        let program =
            if std::path::Path::new("/usr/sbin/mosquitto").exists() { "/usr/sbin/mosquitto" } else { "mosquitto" };
        let log = std::fs::OpenOptions::new().create(true).append(true).open(dir.join("mosquitto.log"));
        let child = Process::new(program)
            .arg("-c")
            .arg(dir.join("mosquitto.conf"))
            .stdout(log.map(Stdio::from).unwrap_or_else(|_| Stdio::null()))
            .stderr(Stdio::null())
            .spawn()
            .expect("mosquitto (Debian: apt-get install mosquitto mosquitto-clients)");
        let deadline = Instant::now() + Duration::from_secs(5);
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "mosquitto did not listen on {port}");
            std::thread::sleep(Duration::from_millis(20));
        }
        child
    }

    /// Stops the broker (its clients lose their connections and what it kept: no persistence),
    /// waits `down`, and starts it again on the same port.
    pub fn restart(&mut self, down: Duration) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        std::thread::sleep(down);
        self.child = Self::run(self.port, &self.dir);
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Publishes `payload` on `topic` at the broker on `port` (Debian's mosquitto_pub).
pub fn publish(port: u16, topic: &str, payload: &str) {
    let ok = Process::new("mosquitto_pub")
        .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-t", topic, "-m", payload])
        .status()
        .expect("mosquitto_pub (Debian: apt-get install mosquitto-clients)");
    assert!(ok.success(), "mosquitto_pub {topic}");
}

/// A subscriber to `test/#`: each message as `retained topic payload`.
pub struct Subscriber {
    child: Child,
    lines: Receiver<String>,
}

impl Subscriber {
    /// A subscriber to `test/#` of the broker on `port`.
    pub fn start(port: u16) -> Self {
        Self::with_args(port, &[])
    }

    /// A subscriber with more options of `mosquitto_sub` (TLS, a user).
    pub fn with_args(port: u16, extra: &[&str]) -> Self {
        let mut child = Process::new("mosquitto_sub")
            .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-t", "test/#", "-F", "%r %t %p"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("mosquitto_sub (Debian: apt-get install mosquitto-clients)");
        let out = child.stdout.take().expect("its output");
        let (tx, lines) = channel();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        // Subscribed before anything is published (retained messages come anyway).
        std::thread::sleep(Duration::from_millis(300));
        Self { child, lines }
    }

    /// The next message on `topic` within `within`, as (retained, payload).
    pub fn next_on(&self, topic: &str, within: Duration) -> Option<(bool, String)> {
        let deadline = Instant::now() + within;
        loop {
            let left = deadline.checked_duration_since(Instant::now())?;
            let line = self.lines.recv_timeout(left).ok()?;
            let mut parts = line.splitn(3, ' ');
            let (retained, t, payload) = (parts.next()?, parts.next()?, parts.next().unwrap_or(""));
            if t == topic {
                return Some((retained == "1", payload.to_string()));
            }
        }
    }

    /// The topics of the messages that arrived and were not read yet (all are taken).
    pub fn pending_topics(&self) -> Vec<String> {
        self.lines.try_iter().filter_map(|line| line.split(' ').nth(1).map(ToString::to_string)).collect()
    }

    /// Every message on `topic` within `within`.
    pub fn all_on(&self, topic: &str, within: Duration) -> Vec<String> {
        let deadline = Instant::now() + within;
        let mut seen = Vec::new();
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    let mut parts = line.splitn(3, ' ');
                    let (_, t, payload) = (parts.next(), parts.next(), parts.next().unwrap_or(""));
                    if t == Some(topic) {
                        seen.push(payload.to_string());
                    }
                }
                Err(_) => break,
            }
        }
        seen
    }
}

impl Drop for Subscriber {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The TLS broker's user name (in its password file).
pub const USER: &str = "module";
/// Its password.
pub const PASSWORD: &str = "s3cret-Pass-9f2";
/// The name the broker's certificate is made for.
pub const HOST: &str = "broker.test";

fn openssl(dir: &Path, args: &[&str]) {
    let ok = Process::new("openssl").current_dir(dir).args(args).status().expect("openssl").success();
    assert!(ok, "openssl {args:?}");
}

/// A CA, a second CA, and a certificate for `broker.test` valid one day signed by the first, in
/// `dir`; the broker's files readable by the broker's user (mosquitto drops root).
pub fn make_pki(dir: &Path) {
    for ca in ["ca", "other"] {
        openssl(dir, &["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", &format!("{ca}.key")]);
        openssl(
            dir,
            &[
                "req",
                "-x509",
                "-new",
                "-key",
                &format!("{ca}.key"),
                "-subj",
                &format!("/CN=rdaq test {ca}"),
                "-days",
                "2",
                "-out",
                &format!("{ca}.pem"),
            ],
        );
        openssl(dir, &["x509", "-in", &format!("{ca}.pem"), "-outform", "DER", "-out", &format!("{ca}.der")]);
    }
    openssl(dir, &["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", "server.key"]);
    openssl(dir, &["req", "-new", "-key", "server.key", "-subj", &format!("/CN={HOST}"), "-out", "server.csr"]);
    std::fs::write(dir.join("san.ext"), format!("subjectAltName=DNS:{HOST}\n")).expect("san");
    openssl(
        dir,
        &[
            "x509",
            "-req",
            "-in",
            "server.csr",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-days",
            "1",
            "-extfile",
            "san.ext",
            "-out",
            "server.pem",
        ],
    );
    let ok = Process::new("mosquitto_passwd").current_dir(dir).args(["-b", "-c", "passwords", USER, PASSWORD]).status();
    assert!(ok.expect("mosquitto_passwd").success());
    for f in ["server.key", "server.pem", "ca.pem", "passwords"] {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(dir.join(f), std::fs::Permissions::from_mode(0o644)).expect("chmod");
    }
}

/// A broker with only a TLS listener and a password file.
pub fn tls_broker() -> Broker {
    Broker::with(|port, dir| {
        make_pki(dir);
        let d = dir.display();
        format!(
            "listener {port} 127.0.0.1\ncafile {d}/ca.pem\ncertfile {d}/server.pem\nkeyfile {d}/server.key\n\
             allow_anonymous false\npassword_file {d}/passwords\n"
        )
    })
}
