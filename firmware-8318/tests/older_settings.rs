//! Spec §1.3: a store written by an older firmware still loads. `fixtures/settings-v1.img` is
//! the settings flash of the host build of 6e1ce2c (settings version 1), after these Modbus
//! writes (`tools/settings-v1-fixtures.py` made it): input type 0Fh (K), CJC offset FF06h
//! (-2.50 °C), enable mask 005Ah. Today's firmware loads every one of them.

use remodaq_board_host::testing::SimModule;
use tokio::time::timeout;
use tokio_modbus::client::{tcp, Reader};

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8318");
const LIMIT: std::time::Duration = std::time::Duration::from_secs(10);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_version_1_store_loads() {
    let dir = std::env::temp_dir().join(format!("remodaq-v1-8318-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let flash = dir.join("module.flash");
    std::fs::copy(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/settings-v1.img"), &flash).unwrap();
    let module = SimModule::start(BIN, &flash);
    let mut ctx = timeout(LIMIT, tcp::connect(module.addr)).await.unwrap().unwrap();
    let mut regs =
        async |addr: u16| timeout(LIMIT, ctx.read_holding_registers(addr, 1)).await.unwrap().unwrap().unwrap();
    assert_eq!(regs(0xC8).await, [0x0F], "input type K");
    assert_eq!(regs(0xD7).await, [0xFF06], "CJC offset -2.50 °C");
    assert_eq!(regs(0xDC).await, [0x005A], "enable mask");
}
