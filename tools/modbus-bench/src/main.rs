//! `modbus-bench IMPL FRAME N`: answers request FRAME N times with implementation IMPL
//! (`project`, `rmodbus` or `libmodbus`), each through one serve function that callgrind
//! collects alone (`tools/modbus-bench/run` does the counting).
//!
//! The project answers the way its connection server does (`serve_frames`): the MBAP header is
//! classified, then `answer_request` answers on the map behind the firmware's lock type
//! (`Mutex<CriticalSectionRawMutex, _>`), here under `embassy_futures::block_on`. The first
//! eight frames are answered from a plain memory map of 1000 bits and 1000 registers; the last
//! four from the modules' own maps (`Map8318`, `Map8350`) as the firmware builds them.
//!
//! The peers answer from their own plain memory maps. For the generic frames these hold the
//! same values as the project's; for the module frames they are seeded with the module's answer
//! (the values, the statuses, the DI states). The RemoDAQ modules have one bit table (codes 01
//! and 02) and one register table (03 and 04): the peers get the same values in both of theirs.
//! Every implementation's last answer is checked against the project's, byte for byte, so all
//! three do the same work.

#[cfg(target_os = "linux")]
mod libmodbus;

use std::hint::black_box;
use std::process::ExitCode;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use remodaq_8318::acquisition::{ChannelStatus, Snapshot};
use remodaq_8318::map::Map8318;
use remodaq_8350::io::{Io, IoCell};
use remodaq_8350::map::Map8350;
use remodaq_modbus::frame::{classify, Frame, MAX_ADU, MBAP_LEN};
use remodaq_modbus::server::answer_request;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::SettingsStore;

/// The firmware's lock around the register map (`remodaq_shared::board::Shared`).
type Shared<M> = Mutex<CriticalSectionRawMutex, M>;

/// The critical section of the single-core firmware (cortex-m's `critical-section-single-core`:
/// PRIMASK saved, interrupts masked, restored): here a saved and restored flag, the same few
/// instructions, where the host's `std` implementation would take a process-wide mutex.
struct SingleCore;
static MASKED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
critical_section::set_impl!(SingleCore);
// SAFETY: the benchmark runs on one thread, as the firmware's executor does; acquire returns
// the previous state and release restores it, which nests correctly.
unsafe impl critical_section::Impl for SingleCore {
    unsafe fn acquire() -> bool {
        use std::sync::atomic::Ordering::Relaxed;
        let was = MASKED.load(Relaxed);
        MASKED.store(true, Relaxed);
        std::sync::atomic::compiler_fence(std::sync::atomic::Ordering::SeqCst);
        was
    }
    unsafe fn release(was: bool) {
        std::sync::atomic::compiler_fence(std::sync::atomic::Ordering::SeqCst);
        MASKED.store(was, std::sync::atomic::Ordering::Relaxed);
    }
}

/// The firmware's time base (a hardware counter read on the boards): here a fixed instant,
/// one load. Nothing in the benchmark waits.
struct Clock;
static NOW: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1_000_000);
embassy_time_driver::time_driver_impl!(static CLOCK: Clock = Clock);
impl embassy_time_driver::Driver for Clock {
    fn now(&self) -> u64 {
        NOW.load(std::sync::atomic::Ordering::Relaxed)
    }
    fn schedule_wake(&self, _: u64, _: &core::task::Waker) {}
}

/// Which map answers a frame.
#[derive(Clone, Copy, PartialEq)]
pub enum On {
    /// The plain memory map.
    Memory,
    /// The 8318's map.
    M8318,
    /// The 8350's map.
    M8350,
}

/// The frames of the comparison (MBAP header + PDU) and the map the project answers them from.
pub const FRAMES: [(&str, On, &[u8]); 12] = [
    ("read holding x10 (03)", On::Memory, &[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 10]),
    ("read holding x125 (03)", On::Memory, &[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 125]),
    ("read input x8 (04)", On::Memory, &[0, 1, 0, 0, 0, 6, 1, 4, 0, 0, 0, 8]),
    ("read coils x100 (01)", On::Memory, &[0, 1, 0, 0, 0, 6, 1, 1, 0, 0, 0, 100]),
    ("write coil (05)", On::Memory, &[0, 1, 0, 0, 0, 6, 1, 5, 0, 7, 0xFF, 0]),
    ("write register (06)", On::Memory, &[0, 1, 0, 0, 0, 6, 1, 6, 0, 7, 0x12, 0x34]),
    (
        "write 10 registers (16)",
        On::Memory,
        &[0, 1, 0, 0, 0, 27, 1, 0x10, 0, 0, 0, 10, 20, 0, 1, 0, 2, 0, 3, 0, 4, 0, 5, 0, 6, 0, 7, 0, 8, 0, 9, 0, 10],
    ),
    ("exception 02 (unmapped read)", On::Memory, &[0, 1, 0, 0, 0, 6, 1, 3, 0x27, 0x10, 0, 1]),
    // 40001-40008: the 8318's eight channel values.
    ("8318 channel values (03 x8)", On::M8318, &[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 8]),
    // 40225-40232: their statuses (extensions §2).
    ("8318 channel statuses (03 x8)", On::M8318, &[0, 1, 0, 0, 0, 6, 1, 3, 0, 0xE0, 0, 8]),
    // 00017: DO0 on.
    ("8350 DO coil (05)", On::M8350, &[0, 1, 0, 0, 0, 6, 1, 5, 0, 0x10, 0xFF, 0]),
    // 00001-00012: the twelve DI states.
    ("8350 DI block (02 x12)", On::M8350, &[0, 1, 0, 0, 0, 6, 1, 2, 0, 0, 0, 12]),
];

const SIZE: usize = 1000;

/// A plain memory map: every address below 1000 of each table, read and write.
pub struct MemoryMap {
    coils: [bool; SIZE],
    holding: [u16; SIZE],
}

/// The initial values: bit n is set when n is a multiple of 3; register n is 7n.
fn bit(n: usize) -> bool {
    n % 3 == 0
}

fn register(n: usize) -> u16 {
    n as u16 * 7
}

impl MemoryMap {
    fn new() -> Self {
        Self { coils: std::array::from_fn(bit), holding: std::array::from_fn(register) }
    }

    #[inline]
    fn store(&mut self, start: u16, values: &WriteValues<'_>) {
        let start = usize::from(start);
        match (values.table(), values.bytes()) {
            // Codes 05 and 06: one value.
            (Table::Bits, &[bit]) if values.len() == 1 => {
                if let Some(c) = self.coils.get_mut(start) {
                    *c = bit & 1 != 0;
                }
                return;
            }
            (Table::Registers, &[hi, lo]) => {
                if let Some(r) = self.holding.get_mut(start) {
                    *r = u16::from_be_bytes([hi, lo]);
                }
                return;
            }
            _ => {}
        }
        match values.table() {
            Table::Bits => {
                for (i, v) in values.flags().enumerate() {
                    if let Some(c) = self.coils.get_mut(start + i) {
                        *c = v;
                    }
                }
            }
            Table::Registers => {
                let (words, _) = values.bytes().as_chunks::<2>();
                // Two slices of the same length: the copy compiles without bounds checks.
                let Some(dst) = self.holding.get_mut(start..start + words.len()) else { return };
                for (r, &w) in dst.iter_mut().zip(words) {
                    *r = u16::from_be_bytes(w);
                }
            }
        }
    }
}

impl RegisterMap for MemoryMap {
    fn access(&self, _: Table, addr: u16) -> Access {
        if usize::from(addr) < SIZE {
            Access::ReadWrite
        } else {
            Access::None
        }
    }
    fn read(&mut self, table: Table, addr: u16) -> u16 {
        match table {
            Table::Bits => u16::from(self.coils[usize::from(addr)]),
            Table::Registers => self.holding[usize::from(addr)],
        }
    }
    fn validate(&self, _: u16, _: &WriteValues<'_>) -> Result<(), Exception> {
        Ok(())
    }
    // Memory only: applied under the lock the checks ran under.
    fn write_now(&mut self, start: u16, values: &WriteValues<'_>) -> Option<Result<(), Exception>> {
        self.store(start, values);
        Some(Ok(()))
    }

    // Runs in one call each: the block access of the RegisterMap trait.
    fn allows(&self, _: Table, start: u16, count: u16, _: bool) -> bool {
        usize::from(start) + usize::from(count) <= SIZE
    }

    fn read_registers(&mut self, start: u16, out: &mut [u8]) {
        let start = usize::from(start);
        for (word, value) in out.chunks_exact_mut(2).zip(&self.holding[start..]) {
            word.copy_from_slice(&value.to_be_bytes());
        }
    }

    fn read_bits(&mut self, start: u16, count: u16, out: &mut [u8]) {
        let bits = &self.coils[usize::from(start)..usize::from(start) + usize::from(count)];
        let mut chunks = bits.chunks_exact(8);
        for (byte, chunk) in out.iter_mut().zip(&mut chunks) {
            // Eight bools (bytes 0 or 1) packed LSB first with one multiply: bit k of byte k
            // lands at bit 56 + k.
            let mut word = [0u8; 8];
            for (w, &b) in word.iter_mut().zip(chunk) {
                *w = u8::from(b);
            }
            *byte = (u64::from_le_bytes(word).wrapping_mul(0x0102_0408_1020_4080) >> 56) as u8;
        }
        if let Some(last) = out.get_mut(bits.len() / 8) {
            for (k, &b) in chunks.remainder().iter().enumerate() {
                *last |= u8::from(b) << k;
            }
        }
    }
}

/// The project's answer to one frame, as its connection server answers: the header
/// classified, then `answer_request` on the map behind its lock.
#[inline(never)]
pub fn serve_project<M: RegisterMap>(map: &Shared<M>, request: &[u8], response: &mut [u8; MAX_ADU]) -> usize {
    let Frame::Request { header, len } = classify(request) else { return 0 };
    let Some(pdu) = request.get(MBAP_LEN..len) else { return 0 };
    embassy_futures::block_on(answer_request(map, [192, 168, 1, 10], header, pdu, response))
}

/// rmodbus's answer to one frame: the request in its frame buffer, the answer in a
/// fixed-capacity vector, as its documentation shows for `no_std` (there of 256 bytes, too
/// small for the answer to 125 registers: here the largest Modbus/TCP frame, 260).
#[inline(never)]
pub fn serve_rmodbus(
    ctx: &mut rmodbus::server::storage::ModbusStorageSmall,
    request: &rmodbus::ModbusFrameBuf,
    response: &mut heapless::Vec<u8, MAX_ADU>,
) -> usize {
    use rmodbus::server::ModbusFrame;
    use rmodbus::ModbusProto;
    response.clear();
    let mut frame = ModbusFrame::new(1, request, ModbusProto::TcpUdp, response);
    if frame.parse().is_err() {
        return 0;
    }
    if frame.processing_required {
        let result = if frame.readonly { frame.process_read(ctx) } else { frame.process_write(ctx) };
        if result.is_err() {
            return 0;
        }
    }
    if frame.response_required && frame.finalize_response().is_ok() {
        return response.len();
    }
    0
}

/// The settings store the module maps are built on: RAM flash, factory settings.
fn store<S: remodaq_shared::settings::Schema>() -> &'static Shared<SettingsStore<RamFlash<4096, 1024>, S>> {
    type Flash = RamFlash<4096, 1024>;
    let store = embassy_futures::block_on(SettingsStore::<Flash, S>::open(
        Flash::new(),
        const { SettingsStore::<Flash, S>::config(0..4096) },
    ));
    Box::leak(Box::new(Mutex::new(store)))
}

/// Answers `request` `n` times with the project on `map`; returns the last answer.
fn run_project<M: RegisterMap>(map: &Shared<M>, request: &[u8], n: u32) -> Vec<u8> {
    let mut out = [0u8; MAX_ADU];
    let mut len = 0;
    for _ in 0..n {
        len = serve_project(map, black_box(request), &mut out);
    }
    out[..len].to_vec()
}

/// The project's answer to frame `on`, `n` times: on its map, built as the firmware builds it.
fn project(on: On, request: &[u8], n: u32) -> Vec<u8> {
    match on {
        On::Memory => run_project(&Mutex::new(MemoryMap::new()), request, n),
        On::M8318 => {
            let store = store::<remodaq_8318::settings::Settings>();
            let settings = *embassy_futures::block_on(store.lock()).get();
            let mut map = Map8318::new(store, &settings);
            // One acquisition cycle: eight type-K readings, 0.1 °C, two of them open.
            let mut snapshot = Snapshot::default();
            snapshot.values = [2512, 2498, 0x7FFF, 1003, 4500, 0x7FFF, 250, 2501];
            snapshot.status = [ChannelStatus::Ok; 8];
            snapshot.status[2] = ChannelStatus::Open;
            snapshot.status[5] = ChannelStatus::Open;
            snapshot.cjc = 2315;
            map.publish(snapshot);
            run_project(&Mutex::new(map), request, n)
        }
        On::M8350 => {
            let store = store::<remodaq_8350::settings::Settings>();
            let settings = *embassy_futures::block_on(store.lock()).get();
            let io: &'static IoCell<CriticalSectionRawMutex> =
                Box::leak(Box::new(IoCell::new(core::cell::RefCell::new(Io::new(10_000, &settings)))));
            // DI 0, 3 and 10 high (inputs are sampled as 12-bit words).
            remodaq_8350::io::with(io, |s| s.di.process(&[0b0100_0000_1001; 4]));
            run_project(&Mutex::new(Map8350::new(store, &settings, io)), request, n)
        }
    }
}

/// The values a peer's memory holds for frame `request`, whose answer is `answer`: for a
/// module frame, what the module answered; otherwise the plain memory map's values.
fn seeded(on: On, request: &[u8], answer: &[u8]) -> (Vec<bool>, Vec<u16>) {
    let mut bits: Vec<bool> = (0..SIZE).map(bit).collect();
    let mut registers: Vec<u16> = (0..SIZE).map(register).collect();
    let (Some(&function), Some(&[s0, s1, q0, q1])) = (request.get(7), request.get(8..12).and_then(|s| s.first_chunk()))
    else {
        return (bits, registers);
    };
    let (start, quantity) = (usize::from(u16::from_be_bytes([s0, s1])), usize::from(u16::from_be_bytes([q0, q1])));
    let data = answer.get(9..).unwrap_or(&[]);
    if on != On::Memory {
        match function {
            1 | 2 => {
                for i in 0..quantity {
                    bits[start + i] = data.get(i / 8).is_some_and(|b| b >> (i % 8) & 1 != 0);
                }
            }
            3 | 4 => {
                for (i, w) in data.chunks_exact(2).enumerate() {
                    registers[start + i] = u16::from_be_bytes([w[0], w[1]]);
                }
            }
            _ => {}
        }
    }
    (bits, registers)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("names") {
        for (name, _, _) in FRAMES {
            println!("{name}");
        }
        return ExitCode::SUCCESS;
    }
    let (Some(which), Some(frame), Some(n)) = (args.get(1), args.get(2), args.get(3)) else {
        eprintln!("usage: modbus-bench project|rmodbus|libmodbus FRAME(0-{}) N", FRAMES.len() - 1);
        eprintln!("       modbus-bench names");
        return ExitCode::from(2);
    };
    let (Ok(frame), Ok(n)) = (frame.parse::<usize>(), n.parse::<u32>()) else { return ExitCode::from(2) };
    let Some(&(_, on, request)) = FRAMES.get(frame) else { return ExitCode::from(2) };
    let reference = project(on, request, 1);
    let (bits, registers) = seeded(on, request, &reference);
    let answer: Vec<u8> = match which.as_str() {
        "project" => project(on, request, n),
        "rmodbus" => {
            use rmodbus::server::context::ModbusContext;
            let mut ctx = rmodbus::server::storage::ModbusStorageSmall::new();
            for (i, (&b, &r)) in bits.iter().zip(&registers).enumerate() {
                let _ = ctx.set_coil(i as u16, b);
                let _ = ctx.set_discrete(i as u16, b);
                let _ = ctx.set_holding(i as u16, r);
                let _ = ctx.set_input(i as u16, r);
            }
            let mut buf: rmodbus::ModbusFrameBuf = [0; 256];
            buf[..request.len()].copy_from_slice(request);
            let mut out = heapless::Vec::<u8, MAX_ADU>::new();
            let mut len = 0;
            for _ in 0..n {
                len = serve_rmodbus(&mut ctx, black_box(&buf), &mut out);
            }
            out[..len].to_vec()
        }
        #[cfg(target_os = "linux")]
        "libmodbus" => libmodbus::run(request, n, &bits, &registers),
        _ => return ExitCode::from(2),
    };
    if answer != reference {
        eprintln!("{which} answered {answer:02x?}, the project {reference:02x?}");
        return ExitCode::from(1);
    }
    ExitCode::SUCCESS
}
