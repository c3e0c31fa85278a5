//! End to end: the host build of the 8350 on a loopback port, driven by tokio-modbus.

use std::time::Duration;

use remodaq_board_host::testing::SimModule;
use tokio::time::timeout;
use tokio_modbus::client::{tcp, Reader, Writer};
use tokio_modbus::ExceptionCode;

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8350");
const LIMIT: Duration = Duration::from_secs(10);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identity_registers() {
    let flash = std::env::temp_dir().join(format!("remodaq-e2e-8350-{}.flash", std::process::id()));
    let _ = std::fs::remove_file(&flash);
    let module = SimModule::start(BIN, &flash);
    let mut ctx = timeout(LIMIT, tcp::connect(module.addr)).await.unwrap().unwrap();
    let name = timeout(LIMIT, ctx.read_holding_registers(0xD2, 1)).await.unwrap().unwrap();
    assert_eq!(name, Ok(vec![0x8350]));
    let version = timeout(LIMIT, ctx.read_input_registers(0xD4, 1)).await.unwrap().unwrap();
    assert_eq!(version, Ok(vec![0xA100]));
    let w = timeout(LIMIT, ctx.write_single_register(0xD4, 0xA200)).await.unwrap().unwrap();
    assert_eq!(w, Err(ExceptionCode::IllegalDataAddress), "version is read only (decision)");
    drop(module);
    let _ = std::fs::remove_file(&flash);
}
