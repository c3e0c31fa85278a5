//! QEMU and its network: the local ports its user network forwards to the guest (from a range
//! of this run's own), and QEMU started as the module starts, killed when dropped.

use std::net::{SocketAddr, TcpListener};
use std::process::{Child, Command, Stdio};

pub(crate) struct Qemu(Child);

impl Qemu {
    /// Stops QEMU (SIGSTOP) or lets it run on (SIGCONT): the module lost, its sockets open and
    /// silent, as a module whose power failed behind a switch (the check of the will).
    pub(crate) fn signal(&self, stop: bool) -> Result<(), String> {
        let signal = if stop { "-STOP" } else { "-CONT" };
        match Command::new("kill").args([signal, &self.0.id().to_string()]).status() {
            Ok(status) if status.success() => Ok(()),
            other => Err(format!("kill {signal} QEMU: {other:?}")),
        }
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Clients of the newcomer check's flood.
pub(crate) const FLOOD: usize = 64;

/// The local ports QEMU's user network forwards to the guest.
pub(crate) struct Ports {
    /// Modbus/TCP (8000).
    modbus: u16,
    /// Discovery (UDP 8300).
    pub(crate) udp: u16,
    /// The update service (TCP 8301).
    pub(crate) update: u16,
    /// The web console (TCP 80).
    pub(crate) web: u16,
    /// One more port to Modbus/TCP for each flood client. QEMU's user network (slirp) listens
    /// on a forwarded port with a backlog of 1: the host's kernel holds two connections it has
    /// not accepted yet and drops the SYNs beyond, which the client sends again only 1 s later.
    /// Through one port, a flood reaches the guest spread over seconds, and a newcomer behind
    /// it waits 1 s for QEMU, not for the module. One port each puts the flood on the guest's
    /// wire at once, as 64 clients on a LAN would.
    pub(crate) flood: Vec<u16>,
}

/// Ports are chosen from a range of this many, one range per run (see [`port_range`]).
const PORT_RANGE: u16 = 4000;
/// The next port of this run's range to try (an offset in it).
static NEXT_PORT: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(0);
/// The first port of this run's range.
static PORT_BASE: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(28_000);

/// Chooses this run's port range from what it runs: each model its own, below Linux's ephemeral
/// ports (32768-60999). The test command runs both models at once: ports chosen by asking the
/// kernel for free ones (port 0) and released until QEMU binds them could be handed to the
/// other run meanwhile, for its QEMU or a client connection.
pub(crate) fn port_range(what: &str) {
    let base = match what {
        "8318" => 20_000,
        "8350" => 24_000,
        _ => 28_000,
    };
    PORT_BASE.store(base, std::sync::atomic::Ordering::Relaxed);
}

/// The next port of this run's range that is free now on the loopback (TCP, or UDP), never
/// one this run chose before (until the range wraps).
fn free_port(udp: bool) -> Result<u16, String> {
    use std::sync::atomic::Ordering::Relaxed;
    for _ in 0..PORT_RANGE {
        let port = PORT_BASE.load(Relaxed) + NEXT_PORT.fetch_add(1, Relaxed) % PORT_RANGE;
        let free = if udp {
            std::net::UdpSocket::bind(("127.0.0.1", port)).is_ok()
        } else {
            TcpListener::bind(("127.0.0.1", port)).is_ok()
        };
        if free {
            return Ok(port);
        }
    }
    Err("no free local port in this run's range".into())
}

impl Ports {
    /// Free local ports for all of them, from this run's range.
    pub(crate) fn free() -> Result<Self, String> {
        let udp = free_port(true)?;
        let tcp = (0..FLOOD + 3).map(|_| free_port(false)).collect::<Result<Vec<_>, _>>()?;
        Ok(Self { modbus: tcp[0], udp, update: tcp[1], web: tcp[2], flood: tcp[3..].to_vec() })
    }

    pub(crate) fn modbus(&self) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], self.modbus))
    }

    /// QEMU's user network with these forwards.
    fn nic(&self) -> String {
        let mut nic = format!(
            "user,id=nic0,model=lan9118,hostfwd=tcp:127.0.0.1:{}-:8000,hostfwd=udp:127.0.0.1:{}-:8300,hostfwd=tcp:127.0.0.1:{}-:8301,hostfwd=tcp:127.0.0.1:{}-:80",
            self.modbus, self.udp, self.update, self.web
        );
        for port in &self.flood {
            nic += &format!(",hostfwd=tcp:127.0.0.1:{port}-:8000");
        }
        nic
    }
}

/// QEMU started as the module starts: the board's bootloader (next to the image) as QEMU's
/// image, the application's raw binary (`IMAGE.bin`, from scripts/qemu build) as its seed.
pub(crate) fn start_qemu(image: &str, ports: &Ports) -> Result<Qemu, String> {
    start_qemu_with(image, ports, None, false)
}

/// QEMU's instruction counting for [`start_qemu_counted`]: the guest's clock advances 8 ns an
/// instruction while the guest runs (125 million a second, the M4's order at 180 MHz) and with
/// the wall clock while it sleeps (WFI).
const ICOUNT: &str = "shift=3,sleep=on";

/// [`start_qemu`] with the guest's clock counting the instructions it runs ([`ICOUNT`]): a
/// time the guest measures between two of its own events (a Modbus request's interrupt and its
/// answer, the QEMU board's `probe`) is then the firmware's work, whatever this PC did to
/// QEMU's threads meanwhile.
pub(crate) fn start_qemu_counted(image: &str, ports: &Ports) -> Result<Qemu, String> {
    start_qemu_with(image, ports, None, true)
}

/// The trial of a new image on the QEMU board, s (`remodaq_update::TRIAL` with the feature
/// `short-trial` that the QEMU images have: docs/update.md): one that has not passed its
/// self-test by then restarts, and the bootloader reverts.
pub(crate) const TRIAL_S: u64 = 10;

/// The QEMU board's test switches word (boards/qemu/layout.x) and its front-end fault value
/// (boards/qemu/src/lib.rs, `test_switches`): "FEND".
const TEST_SWITCHES_ADDR: u32 = 0x003F_F000;
pub(crate) const FRONT_END_FAULT: u32 = 0x4645_4E44;

/// [`start_qemu`], with the board's test switches word set to `switches` at every reset
/// (a hardware fault every image on this machine sees), the guest's clock counting
/// instructions if `counted` ([`start_qemu_counted`]).
pub(crate) fn start_qemu_with(
    image: &str,
    ports: &Ports,
    switches: Option<u32>,
    counted: bool,
) -> Result<Qemu, String> {
    let log = std::fs::File::create(format!("{image}.qemu.log")).map_err(|e| e.to_string())?;
    let bootloader = std::path::Path::new(image).with_file_name("remodaq-qemu-bootloader");
    // An image built before the board had a bootloader (for `latency` comparisons with older
    // builds) boots by itself.
    let boot: Vec<std::ffi::OsString> = if bootloader.exists() {
        let seed = format!("loader,file={image}.bin,addr=0x300000");
        vec!["-kernel".into(), bootloader.into(), "-device".into(), seed.into()]
    } else {
        vec!["-kernel".into(), image.into()]
    };
    // A packet capture of the emulated NIC, for diagnosis: REMODAQ_QEMU_PCAP=FILE.
    let capture = std::env::var("REMODAQ_QEMU_PCAP")
        .map_or(vec![], |file| vec!["-object".to_string(), format!("filter-dump,id=dump,netdev=nic0,file={file}")]);
    let child = Command::new("qemu-system-arm")
        .args(["-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-nic", &ports.nic()])
        .args(capture)
        .args(if counted { ["-icount", ICOUNT].as_slice() } else { &[] })
        .args(boot)
        .args(switches.map_or(vec![], |word| {
            vec!["-device".to_string(), format!("loader,addr={TEST_SWITCHES_ADDR:#x},data={word:#x},data-len=4")]
        }))
        .stdin(Stdio::null())
        .stdout(log.try_clone().map_err(|e| e.to_string())?)
        .stderr(log)
        .spawn()
        .map_err(|e| format!("cannot start qemu-system-arm: {e}"))?;
    Ok(Qemu(child))
}
