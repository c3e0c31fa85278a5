//! End to end: the host build of the 8318 on a loopback port, driven by tokio-modbus.

use std::net::SocketAddr;
use std::time::Duration;

use remodaq_board_host::testing::SimModule;
use tokio::time::timeout;
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::ExceptionCode;

const BIN: &str = env!("CARGO_BIN_EXE_firmware-8318");
const LIMIT: Duration = Duration::from_secs(10);

async fn connect(addr: SocketAddr) -> Context {
    timeout(LIMIT, tcp::connect(addr)).await.expect("connect in time").expect("connect")
}

async fn read(ctx: &mut Context, addr: u16, n: u16) -> Result<Vec<u16>, ExceptionCode> {
    timeout(LIMIT, ctx.read_holding_registers(addr, n)).await.expect("answer in time").expect("transport")
}

fn flash_file(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("remodaq-e2e-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    let _ = std::fs::remove_file(&path);
    path
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identity_registers_and_exceptions() {
    let module = SimModule::start(BIN, &flash_file("identity.flash"));
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xD2, 1).await, Ok(vec![0x8318]));
    assert_eq!(read(&mut ctx, 0xD4, 1).await, Ok(vec![0xA100]));
    let input = timeout(LIMIT, ctx.read_input_registers(0xD2, 1)).await.unwrap().unwrap();
    assert_eq!(input, Ok(vec![0x8318]));
    assert_eq!(read(&mut ctx, 0xD3, 1).await, Err(ExceptionCode::IllegalDataAddress));
    // The 8318 has no bits.
    let coils = timeout(LIMIT, ctx.read_coils(0, 1)).await.unwrap().unwrap();
    assert_eq!(coils, Err(ExceptionCode::IllegalDataAddress));
    let w = timeout(LIMIT, ctx.write_single_register(0xD4, 1)).await.unwrap().unwrap();
    assert_eq!(w, Err(ExceptionCode::IllegalDataAddress));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn settings_survive_a_restart() {
    let flash = flash_file("restart.flash");
    let module = SimModule::start(BIN, &flash);
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xC8, 1).await, Ok(vec![0x0F]), "factory type K");
    let w = timeout(LIMIT, ctx.write_single_register(0xC8, 0x12)).await.unwrap().unwrap();
    assert_eq!(w, Ok(()));
    let w = timeout(LIMIT, ctx.write_single_register(0xC8, 0x07)).await.unwrap().unwrap();
    assert_eq!(w, Err(ExceptionCode::IllegalDataValue), "07 is not a type code");
    let w = timeout(LIMIT, ctx.write_single_register(0xDC, 0x00A5)).await.unwrap().unwrap();
    assert_eq!(w, Ok(()));
    let w = timeout(LIMIT, ctx.write_single_register(0xD7, 0xFF38)).await.unwrap().unwrap(); // -2.00 °C
    assert_eq!(w, Ok(()));
    // Killed right after the acknowledgements: the settings must be in the image already.
    module.kill();
    let module = SimModule::start(BIN, &flash);
    let mut ctx = connect(module.addr).await;
    assert_eq!(read(&mut ctx, 0xC8, 1).await, Ok(vec![0x12]));
    assert_eq!(read(&mut ctx, 0xD7, 1).await, Ok(vec![0xFF38]));
    assert_eq!(read(&mut ctx, 0xDC, 1).await, Ok(vec![0x00A5]));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ninth_client_is_served_and_the_longest_idle_is_closed() {
    let module = SimModule::start(BIN, &flash_file("nine.flash"));
    let mut clients = Vec::new();
    for _ in 0..8 {
        let mut ctx = connect(module.addr).await;
        assert_eq!(read(&mut ctx, 0xD2, 1).await, Ok(vec![0x8318]));
        clients.push(ctx);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // Client 0 is now the longest idle; the 9th client must still get answers.
    let mut ninth = connect(module.addr).await;
    assert_eq!(read(&mut ninth, 0xD4, 1).await, Ok(vec![0xA100]));
    // Clients 1..8 are still served.
    for ctx in clients.iter_mut().skip(1) {
        assert_eq!(read(ctx, 0xD2, 1).await, Ok(vec![0x8318]));
    }
    // Client 0 was closed to make room.
    let evicted = timeout(LIMIT, clients[0].read_holding_registers(0xD2, 1)).await.expect("no hang");
    assert!(evicted.is_err(), "longest-idle connection should have been closed: {evicted:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nine_simultaneous_clients_all_get_answers() {
    let module = SimModule::start(BIN, &flash_file("busy.flash"));
    let addr = module.addr;
    let mut tasks = Vec::new();
    for client in 0..9u16 {
        tasks.push(tokio::spawn(async move {
            // Each client asks 30 times; a connection closed to make room is reopened.
            let mut answers = 0;
            let mut reconnects = 0;
            let mut ctx = connect(addr).await;
            while answers < 30 {
                match timeout(LIMIT, ctx.read_holding_registers(0xD2, 1)).await.expect("answer in time") {
                    Ok(Ok(v)) => {
                        assert_eq!(v, vec![0x8318], "client {client}");
                        answers += 1;
                    }
                    Ok(Err(e)) => panic!("client {client}: exception {e:?}"),
                    Err(_) => {
                        reconnects += 1;
                        assert!(reconnects < 100, "client {client} kept losing its connection");
                        ctx = connect(addr).await;
                    }
                }
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
            reconnects
        }));
    }
    let mut total_reconnects = 0;
    for task in tasks {
        total_reconnects += timeout(Duration::from_secs(60), task).await.expect("clients finish").expect("client ok");
    }
    eprintln!("9 clients x 30 answers; connections closed to make room: {total_reconnects}");
}
