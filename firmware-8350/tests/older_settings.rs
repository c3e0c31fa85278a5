//! Spec §1.3: a store written by an older firmware still loads. `fixtures/settings-v1.img` is
//! the settings flash of the host build of 6e1ce2c (settings version 1, the password as a
//! salted hash), after these Modbus writes (`tools/settings-v1-fixtures.py` made it):
//! DI modes 1 2 3 4 0 1 2 3 4 0 1 2; DO modes 1 0 1 0 0 1; DO0 low 7, high 9, count 11; DO5
//! low 3, high 4, count 0; watchdog 2.5 s (25), mode 1, safe levels 000101b, power-on 101000b.
//! Today's firmware loads every one of them, and the factory password (a hash cannot become a
//! SCRAM credential: docs/security.md, "Migration"), which it reports.

use remodaq_board_host::testing::SimModule;
use remodaq_protocol::discovery::{decode_info, encode_request, info_flags, Request, MAX_DATAGRAM};
use tokio::time::timeout;
use tokio_modbus::client::{tcp, Reader};

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8350");
const LIMIT: std::time::Duration = std::time::Duration::from_secs(10);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_version_1_store_loads() {
    let dir = std::env::temp_dir().join(format!("remodaq-v1-8350-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let flash = dir.join("module.flash");
    std::fs::copy(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/settings-v1.img"), &flash).unwrap();
    let module = SimModule::start(BIN, &flash);
    let mut ctx = timeout(LIMIT, tcp::connect(module.addr)).await.unwrap().unwrap();
    let mut regs =
        async |addr: u16, n: u16| timeout(LIMIT, ctx.read_holding_registers(addr, n)).await.unwrap().unwrap().unwrap();
    assert_eq!(regs(0x100, 12).await, [1, 2, 3, 4, 0, 1, 2, 3, 4, 0, 1, 2], "DI modes");
    assert_eq!(regs(0x110, 6).await, [1, 0, 1, 0, 0, 1], "DO modes");
    assert_eq!(regs(0x18, 2).await, [7, 0], "DO0 low width");
    assert_eq!(regs(0x24, 2).await, [9, 0], "DO0 high width");
    assert_eq!(regs(0x30, 2).await, [11, 0], "DO0 count");
    assert_eq!(
        (regs(0x22, 2).await, regs(0x2E, 2).await, regs(0x3A, 2).await),
        (vec![3, 0], vec![4, 0], vec![0, 0]),
        "DO5"
    );
    assert_eq!(regs(0x130, 5).await, [25, 0b00_0101, 1, 0, 0b10_1000], "watchdog, safe and power-on levels");
    // The password: the factory one, reported as such.
    let socket = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode_request(3, &Request::Search, &mut buf).unwrap();
    socket.send_to(&buf[..n], module.discovery).await.unwrap();
    let mut rx = [0u8; 512];
    let (n, _) = timeout(LIMIT, socket.recv_from(&mut rx)).await.unwrap().unwrap();
    let info = decode_info(&rx[..n]).unwrap();
    assert_eq!(info.flags & info_flags::FACTORY_PASSWORD, info_flags::FACTORY_PASSWORD);
}
