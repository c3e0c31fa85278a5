//! `modbus-bench IMPL FRAME N`: answers request FRAME N times with implementation IMPL
//! (`project`, `rmodbus` or `libmodbus`), each through one serve function that callgrind
//! collects alone (`tools/modbus-bench/run` does the counting). Every implementation answers
//! from a plain memory map of 1000 bits and 1000 registers of each table. The RemoDAQ modules
//! have one bit table (codes 01 and 02) and one register table (03 and 04): the other two
//! implementations get the same values in both of theirs. The last answer is checked against
//! the project's, so the three do the same work.

#[cfg(target_os = "linux")]
mod libmodbus;

use std::hint::black_box;
use std::process::ExitCode;

use remodaq_shared::modbus::frame::MAX_ADU;
use remodaq_shared::modbus::{Access, Exception, RegisterMap, Table, WriteValues};

/// The eight frames of the comparison (MBAP header + PDU).
pub const FRAMES: [(&str, &[u8]); 8] = [
    ("read holding x10 (03)", &[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 10]),
    ("read holding x125 (03)", &[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 125]),
    ("read input x8 (04)", &[0, 1, 0, 0, 0, 6, 1, 4, 0, 0, 0, 8]),
    ("read coils x100 (01)", &[0, 1, 0, 0, 0, 6, 1, 1, 0, 0, 0, 100]),
    ("write coil (05)", &[0, 1, 0, 0, 0, 6, 1, 5, 0, 7, 0xFF, 0]),
    ("write register (06)", &[0, 1, 0, 0, 0, 6, 1, 6, 0, 7, 0x12, 0x34]),
    (
        "write 10 registers (16)",
        &[0, 1, 0, 0, 0, 27, 1, 0x10, 0, 0, 0, 10, 20, 0, 1, 0, 2, 0, 3, 0, 4, 0, 5, 0, 6, 0, 7, 0, 8, 0, 9, 0, 10],
    ),
    ("exception 02 (unmapped read)", &[0, 1, 0, 0, 0, 6, 1, 3, 0x27, 0x10, 0, 1]),
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
    fn new() -> Box<Self> {
        let mut m = Box::new(Self { coils: [false; SIZE], holding: [0; SIZE] });
        for i in 0..SIZE {
            m.coils[i] = bit(i);
            m.holding[i] = register(i);
        }
        m
    }
}

impl MemoryMap {
    #[inline]
    fn write(&mut self, start: u16, values: &WriteValues<'_>) {
        let start = usize::from(start);
        match (values.table(), values.bytes()) {
            // Codes 05 and 06: one value.
            (Table::Bits, &[bit]) if values.len() == 1 => {
                self.coils[start] = bit & 1 != 0;
                return;
            }
            (Table::Registers, &[hi, lo]) => {
                self.holding[start] = u16::from_be_bytes([hi, lo]);
                return;
            }
            _ => {}
        }
        match values.table() {
            Table::Bits => {
                for (i, v) in values.flags().enumerate() {
                    self.coils[start + i] = v;
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
    async fn apply(&mut self, start: u16, values: &WriteValues<'_>) -> Result<(), Exception> {
        self.write(start, values);
        Ok(())
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

/// The project's answer to one frame: framing, PDU engine, the map.
#[inline(never)]
pub fn serve_project(map: &mut MemoryMap, request: &[u8], response: &mut [u8; MAX_ADU]) -> usize {
    remodaq_shared::modbus::server::answer_now(map, request, response).unwrap_or(0)
}

/// rmodbus's answer to one frame, into a reused buffer.
#[inline(never)]
pub fn serve_rmodbus(
    ctx: &mut rmodbus::server::storage::ModbusStorageSmall,
    request: &[u8],
    response: &mut Vec<u8>,
) -> usize {
    use rmodbus::server::ModbusFrame;
    use rmodbus::ModbusProto;
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

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let (Some(which), Some(frame), Some(n)) = (args.get(1), args.get(2), args.get(3)) else {
        eprintln!("usage: modbus-bench project|rmodbus|libmodbus FRAME(0-7) N");
        return ExitCode::from(2);
    };
    let (Ok(frame), Ok(n)) = (frame.parse::<usize>(), n.parse::<u32>()) else { return ExitCode::from(2) };
    let Some(&(_, request)) = FRAMES.get(frame) else { return ExitCode::from(2) };
    let mut reference = [0u8; MAX_ADU];
    let reference_len = serve_project(&mut MemoryMap::new(), request, &mut reference);
    let answer: Vec<u8> = match which.as_str() {
        "project" => {
            let mut map = MemoryMap::new();
            let mut out = [0u8; MAX_ADU];
            let mut len = 0;
            for _ in 0..n {
                len = serve_project(&mut map, black_box(request), &mut out);
            }
            out[..len].to_vec()
        }
        "rmodbus" => {
            let mut ctx = rmodbus::server::storage::ModbusStorageSmall::new();
            for i in 0..SIZE {
                use rmodbus::server::context::ModbusContext;
                let _ = ctx.set_coil(i as u16, bit(i));
                let _ = ctx.set_discrete(i as u16, bit(i));
                let _ = ctx.set_holding(i as u16, register(i));
                let _ = ctx.set_input(i as u16, register(i));
            }
            let mut out = Vec::with_capacity(MAX_ADU);
            let mut len = 0;
            for _ in 0..n {
                len = serve_rmodbus(&mut ctx, black_box(request), &mut out);
            }
            out[..len].to_vec()
        }
        #[cfg(target_os = "linux")]
        "libmodbus" => libmodbus::run(request, n),
        _ => return ExitCode::from(2),
    };
    if answer != reference[..reference_len] {
        eprintln!("{which} answered {answer:02x?}, the project {:02x?}", &reference[..reference_len]);
        return ExitCode::from(1);
    }
    ExitCode::SUCCESS
}
