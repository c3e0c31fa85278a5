//! End to end on the host build: the host watchdog and safe state (extensions §3), the write
//! allow-list and per-source lock-out (§4), and Modbus reads answered while the settings flash
//! commits (§4), over loopback with tokio-modbus and the discovery protocol.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use remodaq_board_host::testing::SimModule;
use remodaq_protocol::access::{AllowList, Network};
use remodaq_protocol::discovery::client::{transact, Ask};
use remodaq_protocol::discovery::{decode_info, encode_request, info_flags, Reply, Request, Status, MAX_DATAGRAM};
use remodaq_protocol::m8350::{
    wd_mode, BIT_DO, REG_DI_MODE, REG_DO_MODE, REG_POWER_ON, REG_PULSE, REG_SAFE_VALUES, REG_WD_MODE, REG_WD_STATUS,
    REG_WD_TIMEOUT,
};
use tokio::net::{TcpSocket, UdpSocket};
use tokio::time::{sleep, timeout};
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::ExceptionCode;

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8350");
const LIMIT: Duration = Duration::from_secs(10);
const REG_ALL_DO: u16 = 0x12E;
const REG_MODULE_STATUS: u16 = 0xF0;

fn temp(name: &str) -> PathBuf {
    remodaq_board_host::testing::temp("ext-8350", name)
}

async fn connect(addr: SocketAddr) -> Context {
    timeout(LIMIT, tcp::connect(addr)).await.expect("connect in time").expect("connect")
}

/// A connection whose source address is `from` (a loopback address).
async fn connect_from(from: [u8; 4], addr: SocketAddr) -> Context {
    let socket = TcpSocket::new_v4().unwrap();
    socket.bind(SocketAddr::from((from, 0))).expect("bind a loopback source");
    let stream = timeout(LIMIT, socket.connect(addr)).await.unwrap().expect("connect");
    tcp::attach(stream)
}

async fn regs(ctx: &mut Context, addr: u16, n: u16) -> Vec<u16> {
    timeout(LIMIT, ctx.read_holding_registers(addr, n)).await.unwrap().unwrap().expect("no exception")
}

async fn dos(ctx: &mut Context) -> Vec<bool> {
    timeout(LIMIT, ctx.read_coils(BIT_DO, 6)).await.unwrap().unwrap().expect("no exception")
}

async fn write_reg(ctx: &mut Context, addr: u16, value: u16) -> Result<(), ExceptionCode> {
    timeout(LIMIT, ctx.write_single_register(addr, value)).await.unwrap().unwrap()
}

async fn write_regs(ctx: &mut Context, addr: u16, values: &[u16]) -> Result<(), ExceptionCode> {
    timeout(LIMIT, ctx.write_multiple_registers(addr, values)).await.unwrap().unwrap()
}

async fn write_bit(ctx: &mut Context, addr: u16, on: bool) -> Result<(), ExceptionCode> {
    timeout(LIMIT, ctx.write_single_coil(addr, on)).await.unwrap().unwrap()
}

fn levels(bits: &[bool]) -> u16 {
    bits.iter().enumerate().filter(|(_, b)| **b).fold(0, |acc, (n, _)| acc | 1 << n)
}

/// With polling stopped, reads until the watchdog status shows a trip; returns (the last
/// read still untripped: sent, the first tripped read: answered), from `since`. In
/// writes-only mode the reads do not feed the watchdog.
async fn wait_trip(ctx: &mut Context, since: Instant) -> (Duration, Duration) {
    let mut last_ok = Duration::ZERO;
    loop {
        let sent = Instant::now();
        let status = regs(ctx, REG_WD_STATUS, 1).await[0];
        if status == 1 {
            return (last_ok, since.elapsed());
        }
        last_ok = sent - since;
        assert!(since.elapsed() < Duration::from_secs(5), "no trip within 5 s");
        sleep(Duration::from_millis(2)).await;
    }
}

/// Extensions §3: a 0.5 s watchdog trips 500-600 ms after the last feeding write. The arming
/// write took effect between its sending (`since`) and its answer (`armed` later); the trip
/// lies between the last read that saw none (sent `last_ok` after `since`) and the answer of
/// the first that saw it (`tripped`). The check fails only when the trip was provably outside
/// the window, however slow the machine: [last_ok - armed, tripped] must meet [500, 600] ms.
fn assert_trip_within_spec(armed: Duration, last_ok: Duration, tripped: Duration) {
    let earliest = last_ok.saturating_sub(armed);
    eprintln!("watchdog 0.5 s: the trip lies between {earliest:?} and {tripped:?} after the arming write");
    assert!(tripped >= Duration::from_millis(500), "a trip needs 0.5 s without a write: seen at {tripped:?}");
    assert!(earliest <= Duration::from_millis(600), "tripped later than 0.6 s: not before {earliest:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn host_watchdog_safe_state_clears_power_on_and_persistence() {
    let flash = temp("watchdog.flash");
    let module = SimModule::start(BIN, &flash);
    let mut ctx = connect(module.addr).await;

    // DO0: a continuous 500 Hz pulse train; DO1 on. Safe: only DO2 on. Power-on: only DO3.
    write_reg(&mut ctx, REG_DO_MODE, 1).await.unwrap();
    write_bit(&mut ctx, BIT_DO, true).await.unwrap();
    write_bit(&mut ctx, BIT_DO + 1, true).await.unwrap();
    write_reg(&mut ctx, REG_SAFE_VALUES, 0b00_0100).await.unwrap();
    write_reg(&mut ctx, REG_POWER_ON, 0b00_1000).await.unwrap();
    // Out of range: exception 03, nothing changes.
    assert_eq!(write_reg(&mut ctx, REG_WD_TIMEOUT, 6001).await, Err(ExceptionCode::IllegalDataValue));
    assert_eq!(write_reg(&mut ctx, REG_SAFE_VALUES, 0x40).await, Err(ExceptionCode::IllegalDataValue));
    assert_eq!(write_reg(&mut ctx, REG_WD_MODE, 4).await, Err(ExceptionCode::IllegalDataValue));
    // 0.5 s, fed by writes only (so reading the status does not feed it), manual clear.
    write_reg(&mut ctx, REG_WD_MODE, wd_mode::WRITES_ONLY).await.unwrap();
    let armed = Instant::now();
    write_reg(&mut ctx, REG_WD_TIMEOUT, 5).await.unwrap();
    let answered = armed.elapsed();
    assert_eq!(levels(&dos(&mut ctx).await), 0b00_0011, "DO0 train running, DO1 on");

    let (last_ok, tripped) = wait_trip(&mut ctx, armed).await;
    assert_trip_within_spec(answered, last_ok, tripped);
    assert_eq!(levels(&dos(&mut ctx).await), 0b00_0100, "safe levels: the train stopped, DO1 off, DO2 on");
    assert_eq!(regs(&mut ctx, REG_MODULE_STATUS, 1).await[0] & 0x10, 0x10, "module status bit 4");

    // Tripped: writes that would move an output answer 04 and change nothing; others work.
    let refused = Err(ExceptionCode::ServerDeviceFailure);
    assert_eq!(write_bit(&mut ctx, BIT_DO + 1, true).await, refused, "DO bit");
    assert_eq!(write_reg(&mut ctx, REG_ALL_DO, 0b11_1111).await, refused, "all DO");
    assert_eq!(write_reg(&mut ctx, REG_DO_MODE + 1, 1).await, refused, "DO mode");
    assert_eq!(write_regs(&mut ctx, REG_PULSE, &[20, 0]).await, refused, "pulse width");
    assert_eq!(levels(&dos(&mut ctx).await), 0b00_0100, "nothing moved");
    assert_eq!(regs(&mut ctx, REG_DO_MODE + 1, 1).await, [0], "DO1 mode unchanged");
    write_reg(&mut ctx, REG_DI_MODE, 1).await.expect("a DI mode write works while tripped");
    assert_eq!(regs(&mut ctx, REG_WD_STATUS, 1).await, [1], "a write does not clear it in manual mode");

    // Manual clear: only 0 may be written.
    assert_eq!(write_reg(&mut ctx, REG_WD_STATUS, 1).await, Err(ExceptionCode::IllegalDataValue));
    write_reg(&mut ctx, REG_WD_STATUS, 0).await.unwrap();
    assert_eq!(regs(&mut ctx, REG_WD_STATUS, 1).await, [0]);
    assert_eq!(regs(&mut ctx, REG_MODULE_STATUS, 1).await[0] & 0x10, 0, "module status bit 4 cleared");
    assert_eq!(levels(&dos(&mut ctx).await), 0b00_0100, "outputs stay at their safe levels until written");
    write_bit(&mut ctx, BIT_DO + 1, true).await.expect("written after the clear");
    assert_eq!(levels(&dos(&mut ctx).await), 0b00_0110);

    // Automatic clear: the next write (a feeding request) ends the safe state.
    let armed = Instant::now();
    write_reg(&mut ctx, REG_WD_MODE, wd_mode::WRITES_ONLY | wd_mode::AUTO_CLEAR).await.unwrap();
    let answered = armed.elapsed();
    let (last_ok, tripped) = wait_trip(&mut ctx, armed).await;
    assert_trip_within_spec(answered, last_ok, tripped);
    assert_eq!(levels(&dos(&mut ctx).await), 0b00_0100);
    write_reg(&mut ctx, REG_DI_MODE, 0).await.unwrap();
    assert_eq!(regs(&mut ctx, REG_WD_STATUS, 1).await, [0], "cleared by the write");

    // Any request feeds it (mode 0): polling every 100 ms for 1.5 s, no trip.
    write_reg(&mut ctx, REG_WD_MODE, 0).await.unwrap();
    for _ in 0..15 {
        sleep(Duration::from_millis(100)).await;
        assert_eq!(regs(&mut ctx, REG_WD_STATUS, 1).await, [0], "fed by reads");
    }

    // After a restart: the settings are kept, the outputs take their power-on values, and a
    // module nobody talks to does not trip (the first request arms it).
    drop(ctx);
    module.kill();
    let module = SimModule::start(BIN, &flash);
    sleep(Duration::from_millis(1200)).await;
    let mut ctx = connect(module.addr).await;
    assert_eq!(regs(&mut ctx, REG_WD_TIMEOUT, 5).await, [5, 0b00_0100, 0, 0, 0b00_1000], "persisted, not tripped");
    assert_eq!(levels(&dos(&mut ctx).await), 0b00_1000, "power-on values");
    assert_eq!(regs(&mut ctx, REG_DO_MODE, 1).await, [1], "DO0 still in pulse mode, not running");
    // Armed now by those reads: silence trips it.
    sleep(Duration::from_millis(800)).await;
    let mut other = connect(module.addr).await;
    write_reg(&mut other, REG_WD_TIMEOUT, 0).await.unwrap();
    assert_eq!(regs(&mut other, REG_WD_STATUS, 1).await, [1], "tripped after 0.5 s of silence");
    assert_eq!(levels(&dos(&mut other).await), 0b00_0100);
}

/// One authenticated discovery command from `from` (challenge, proof, the module's signed
/// answer), in a blocking task.
async fn command(to: SocketAddr, from: [u8; 4], mac: [u8; 6], password: &'static str, ask: Ask<'static>) -> Reply {
    tokio::task::spawn_blocking(move || {
        let socket = std::net::UdpSocket::bind(SocketAddr::from((from, 0))).unwrap();
        socket.set_read_timeout(Some(LIMIT)).unwrap();
        let send = |bytes: &[u8]| {
            socket.send_to(bytes, to).ok()?;
            let mut rx = [0u8; 512];
            socket.recv_from(&mut rx).ok().map(|(n, _)| rx[..n].to_vec())
        };
        transact(mac, password.as_bytes(), ask, [from[3]; 16], 3, send).expect("a genuine answer").0
    })
    .await
    .unwrap()
}

/// The password these tests set (allow-list changes are refused while the factory one is in force).
const PASSWORD: &str = "plant password";

fn new_password(new: &'static str) -> Ask<'static> {
    Ask::SetPassword { new: new.as_bytes(), salt: [9; 16], iterations: 4096, secret: [8; 32] }
}

async fn discover(to: SocketAddr, from: [u8; 4], request: &Request) -> Vec<u8> {
    let socket = UdpSocket::bind(SocketAddr::from((from, 0))).await.unwrap();
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(1, request, &mut buf).unwrap();
    socket.send_to(&buf[..n], to).await.unwrap();
    let mut rx = [0u8; 512];
    let (n, _) = timeout(LIMIT, socket.recv_from(&mut rx)).await.expect("a reply").unwrap();
    rx[..n].to_vec()
}

async fn mac(module: &SimModule) -> [u8; 6] {
    decode_info(&discover(module.discovery, [127, 0, 0, 1], &Request::Search).await).unwrap().mac
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn allow_list_and_per_source_lock_out() {
    let flash = temp("access.flash");
    let module = SimModule::start(BIN, &flash);
    let mac = mac(&module).await;
    let list = AllowList::of(&[Network::new([127, 0, 0, 2], 32).unwrap()]).unwrap();
    let d = module.discovery;
    let first = command(d, [127, 0, 0, 1], mac, "remodaq", Ask::SetAccess(list)).await;
    assert_eq!(first.status, Status::SetPasswordFirst, "not with the factory password");
    assert_eq!(command(d, [127, 0, 0, 1], mac, "remodaq", new_password(PASSWORD)).await.status, Status::Ok);
    assert_eq!(command(d, [127, 0, 0, 1], mac, PASSWORD, Ask::SetAccess(list)).await.status, Status::Ok);

    let mut outside = connect_from([127, 0, 0, 1], module.addr).await;
    let mut inside = connect_from([127, 0, 0, 2], module.addr).await;
    let refused = Err(ExceptionCode::IllegalFunction);
    assert_eq!(write_reg(&mut outside, REG_DI_MODE, 1).await, refused, "06 from outside the list");
    assert_eq!(write_regs(&mut outside, REG_DI_MODE, &[1, 1]).await, refused, "16");
    assert_eq!(write_bit(&mut outside, BIT_DO, true).await, refused, "05");
    let r = timeout(LIMIT, outside.write_multiple_coils(BIT_DO, &[true, true])).await.unwrap().unwrap();
    assert_eq!(r, refused, "15");
    assert_eq!(regs(&mut outside, REG_DI_MODE, 2).await, [0, 0], "reads are served; nothing changed");
    assert_eq!(dos(&mut outside).await, [false; 6]);
    write_reg(&mut inside, REG_DI_MODE, 1).await.expect("127.0.0.2 may write");
    assert_eq!(regs(&mut outside, REG_DI_MODE, 1).await, [1]);
    let flags = decode_info(&discover(module.discovery, [127, 0, 0, 1], &Request::Search).await).unwrap().flags;
    assert_eq!(flags & info_flags::WRITES_RESTRICTED, info_flags::WRITES_RESTRICTED, "a search says so");

    // Extensions §4: the list is persisted: after a restart it is still in force.
    drop((outside, inside));
    module.kill();
    let module = SimModule::start(BIN, &flash);
    let d = module.discovery;
    assert_eq!(decode_info(&discover(d, [127, 0, 0, 1], &Request::Search).await).unwrap().mac, mac, "the same module");
    let mut outside = connect_from([127, 0, 0, 1], module.addr).await;
    assert_eq!(write_reg(&mut outside, REG_DI_MODE, 0).await, refused, "still refused after the restart");
    let mut inside = connect_from([127, 0, 0, 2], module.addr).await;
    write_reg(&mut inside, REG_DI_MODE + 1, 1).await.expect("127.0.0.2 may still write");

    // The guessing budget: 127.0.0.3 spends its share (5) and waits; 127.0.0.1 is still checked.
    for _ in 0..5 {
        assert_eq!(command(d, [127, 0, 0, 3], mac, "guess", Ask::GetAccess).await.status, Status::WrongPassword);
    }
    let locked = command(d, [127, 0, 0, 3], mac, PASSWORD, Ask::GetAccess).await;
    assert_eq!(locked.status, Status::RateLimited, "the guessing source waits");
    let admin = command(d, [127, 0, 0, 1], mac, PASSWORD, Ask::GetAccess).await;
    assert_eq!((admin.status, admin.list), (Status::Ok, Some(list)), "another source is checked");

    // Cleared: anyone may write again.
    let clear = command(d, [127, 0, 0, 1], mac, PASSWORD, Ask::SetAccess(AllowList::EMPTY)).await;
    assert_eq!(clear.status, Status::Ok);
    write_reg(&mut outside, REG_DI_MODE, 0).await.expect("writes allowed again");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reads_are_answered_while_the_flash_commits() {
    // Every flash write and erase takes 200 ms longer: a commit takes a second or more.
    let module = SimModule::start_with(BIN, &temp("slow.flash"), &["--listen", "127.0.0.1:0", "--slow-flash", "200"]);
    let addr = module.addr;
    let mac = mac(&module).await;
    let mut reader = connect(addr).await;
    regs(&mut reader, REG_DI_MODE, 1).await;

    for what in ["a Modbus write of a persisted register", "a password change over discovery"] {
        let started = Instant::now();
        let commit = if what.starts_with("a Modbus") {
            tokio::spawn(async move {
                let mut writer = connect(addr).await;
                write_reg(&mut writer, REG_DI_MODE + 3, 4).await.unwrap();
                started.elapsed()
            })
        } else {
            let to = module.discovery;
            tokio::spawn(async move {
                let change = new_password(PASSWORD);
                assert_eq!(command(to, [127, 0, 0, 1], mac, "remodaq", change).await.status, Status::Ok);
                started.elapsed()
            })
        };
        sleep(Duration::from_millis(50)).await;
        let mut worst = Duration::ZERO;
        let mut reads = 0;
        while !commit.is_finished() {
            let t = Instant::now();
            regs(&mut reader, REG_DI_MODE, 12).await;
            worst = worst.max(t.elapsed());
            reads += 1;
            sleep(Duration::from_millis(20)).await;
        }
        let took = commit.await.unwrap();
        eprintln!("{what}: commit took {took:?}; {reads} reads meanwhile, the slowest {worst:?}");
        assert!(took >= Duration::from_millis(300), "the commit was slow: {took:?}");
        assert!(reads >= 5, "reads went on during the commit: {reads}");
        // A read that waited for the store would wait for at least one flash operation, 200 ms
        // here: the bound comes from the injected delay, not from this machine's speed.
        assert!(worst < Duration::from_millis(200), "no read waited for a flash operation: {worst:?}");
    }
    assert_eq!(regs(&mut reader, REG_DI_MODE + 3, 1).await, [4], "the write took effect");
}

/// With an allow-list set, a client outside it cannot keep the host watchdog fed: its reads are
/// served, but the outputs still go to their safe levels when the listed master goes silent
/// (docs/security.md).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_allow_listed_clients_feed_the_host_watchdog() {
    let module = SimModule::start(BIN, &temp("wd-access.flash"));
    let (mac, d) = (mac(&module).await, module.discovery);
    assert_eq!(command(d, [127, 0, 0, 1], mac, "remodaq", new_password(PASSWORD)).await.status, Status::Ok);
    let list = AllowList::of(&[Network::new([127, 0, 0, 2], 32).unwrap()]).unwrap();
    assert_eq!(command(d, [127, 0, 0, 1], mac, PASSWORD, Ask::SetAccess(list)).await.status, Status::Ok);
    let mut master = connect_from([127, 0, 0, 2], module.addr).await;
    let mut outsider = connect_from([127, 0, 0, 9], module.addr).await;
    // The master arms a 0.5 s watchdog fed by any request, then goes silent.
    write_reg(&mut master, REG_WD_MODE, 0).await.unwrap();
    write_reg(&mut master, REG_WD_TIMEOUT, 5).await.unwrap();
    let armed = Instant::now();
    // The outsider polls every 100 ms: its reads are answered, and feed nothing.
    loop {
        let status = regs(&mut outsider, REG_WD_STATUS, 1).await[0];
        if status == 1 {
            break;
        }
        assert!(armed.elapsed() < Duration::from_secs(3), "the outsider's reads kept the watchdog fed");
        sleep(Duration::from_millis(100)).await;
    }
    let tripped = armed.elapsed();
    eprintln!("tripped {tripped:?} after the master's last write, with the outsider polling");
    assert!(tripped >= Duration::from_millis(450), "{tripped:?}");
}

/// Alternating writes of a persisted register cannot wear the settings flash out: a write that
/// changes nothing is not committed, and beyond the commit budget (a burst of 100 after a
/// power-on, one more every 3 minutes: docs/security.md) a write answers exception 04,
/// changes nothing, and is counted (40256).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn alternating_writes_meet_the_commit_budget() {
    let module = SimModule::start(BIN, &temp("wear.flash"));
    let mut ctx = connect(module.addr).await;
    for _ in 0..200 {
        write_reg(&mut ctx, REG_DI_MODE, 0).await.expect("the same value: nothing to commit");
    }
    let mut committed = 0;
    let refused = loop {
        match write_reg(&mut ctx, REG_DI_MODE, (committed % 2 + 1) as u16).await {
            Ok(()) => committed += 1,
            Err(e) => break e,
        }
        assert!(committed <= 100, "more than the budget's burst of 100 commits");
    };
    assert_eq!((committed, refused), (100, ExceptionCode::ServerDeviceFailure), "the burst after a power-on");
    assert_eq!(regs(&mut ctx, REG_DI_MODE, 1).await, [2], "the refused write changed nothing");
    assert_eq!(regs(&mut ctx, 0x00FF, 1).await, [1], "counted in 40256");
    write_reg(&mut ctx, REG_DI_MODE, 2).await.expect("the value in force: still answered");
}

/// Security review finding 1: on an unclaimed module anyone may prove the factory password,
/// change the network settings and restart the module. Under it, the web console's and
/// discovery's commits share the administration's budget (docs/security.md, "Flash wear": a
/// burst of 20): beyond it a change answers 429 (web) or its own status (discovery), changes
/// nothing and is counted in 40256, and a restart renews nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn factory_password_commits_meet_a_budget_that_a_restart_does_not_renew() {
    use remodaq_board_host::testing::web::{log_in, request};
    use remodaq_protocol::net::NetConfig;
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let http = format!("127.0.0.1:{port}");
    let mut module =
        SimModule::start_with(BIN, &temp("admin-wear.flash"), &["--listen", "127.0.0.1:0", "--http", &http]);
    let web = module.web.expect("web address");
    let body = |modbus: u16| {
        format!(
            r#"{{"ip":"192.0.2.10","mask":"255.255.255.0","gateway":"192.0.2.1","modbus_port":{modbus},"http_port":{port}}}"#
        )
    };
    let put = |page: &mut remodaq_board_host::testing::web::Page, modbus: u16| {
        let b = body(modbus);
        request(web, "PUT", "/api/v1/network", &page.sign("PUT", "/api/v1/network", &b), &b).status
    };
    let mut page = log_in(web, "remodaq").unwrap_or_else(|a| panic!("login: {} {}", a.status, a.body));
    // The burst alternates 8001 and 8002; beyond it, each asks for the port not in force.
    let statuses: Vec<u16> = (0..24u16).map(|n| put(&mut page, 8001 + n.min(20) % 2)).collect();
    assert_eq!(statuses[..20], [204; 20], "{statuses:?}");
    assert_eq!(statuses[20..], [429; 4], "{statuses:?}");
    // Discovery draws on the same budget.
    let mac = mac(&module).await;
    let net = NetConfig { ip: [192, 0, 2, 10], mask: [255, 255, 255, 0], gateway: [192, 0, 2, 1], port: 8001 };
    let refused = command(module.discovery, [127, 0, 0, 1], mac, "remodaq", Ask::SetNetwork(net)).await;
    assert_eq!(refused.status, Status::CommitBudget);
    let stored =
        |module: &SimModule| decode_info(&remodaq_board_host::testing::search(module.discovery)).expect("INFO").stored;
    assert_eq!(stored(&module).port, 8002, "the refused changes changed nothing");
    let mut ctx = connect(module.addr).await;
    assert_eq!(regs(&mut ctx, 0x00FF, 1).await, [5], "counted in 40256");
    drop(ctx);
    // A restart (anyone may: the password is the factory one) renews nothing.
    let restart = request(web, "POST", "/api/v1/restart", &page.sign("POST", "/api/v1/restart", ""), "");
    assert_eq!(restart.status, 202, "{}", restart.body);
    module.wait_listening();
    let mut page =
        log_in(web, "remodaq").unwrap_or_else(|a| panic!("login after the restart: {} {}", a.status, a.body));
    assert_eq!(put(&mut page, 8001), 429, "a restart renewed the budget");
    assert_eq!(stored(&module).port, 8002);
    let mut ctx = connect(module.addr).await;
    assert_eq!(regs(&mut ctx, 0x00FF, 1).await, [1], "counted in 40256 since the restart");
    // What the restart carried over, not a budget emptied for want of it: the Modbus writes'
    // budget, untouched before, still holds its burst.
    write_reg(&mut ctx, REG_DI_MODE, 1).await.expect("a Modbus write commits after the restart");
}

/// Issue #23: a DO write reaches the output pattern within 1 ms, not at the next refill (6.4 to
/// 12.8 ms): the module measures each command from its write to the first tick that plays it
/// (40326, worst 40327). Here 200 writes of DO0, each read back 15 ms later. The median and 95 %
/// of the writes are held to the goal; the worst is shown, not held: the simulated module
/// shares this PC's two cores with the other tests, and a process put aside by the OS for a few
/// ms is not the module's design.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_do_write_reaches_the_pattern_within_1_ms() {
    const REG_OUTPUT_LATENCY: u16 = 0x145;
    let module = SimModule::start(BIN, &temp("latency.flash"));
    let mut ctx = connect(module.addr).await;
    let mut seen = Vec::new();
    for i in 0..200 {
        write_bit(&mut ctx, BIT_DO, i % 2 == 0).await.unwrap();
        sleep(Duration::from_millis(15)).await;
        seen.push(regs(&mut ctx, REG_OUTPUT_LATENCY, 1).await[0]);
    }
    seen.sort_unstable();
    let (median, p95, worst) = (seen[100], seen[190], seen[199]);
    eprintln!("DO write to the output pattern, 200 writes: median {median} µs, 95 % {p95} µs, worst {worst} µs");
    assert!(median <= 1000 && p95 <= 1000, "median {median} µs, 95 % {p95} µs");
    let worst_since_start = regs(&mut ctx, REG_OUTPUT_LATENCY + 1, 1).await[0];
    assert!(worst_since_start >= worst, "40327 reads {worst_since_start} µs, below the worst seen");
}
