//! A register-level fake of the AD7124-8: it decodes the communications byte, keeps the
//! register file, and converts the configured channel's input voltage with the configured gain,
//! as the datasheet describes. Its reset lasts 2 ms of embassy-time's clock: wall-clock time in
//! the main workspace's tests, and in shared/clock-tests a mock clock that moves only while the
//! driver waits, so that a driver that does not wait out the reset always fails there.
#![allow(dead_code)]

use std::collections::HashMap;

use embedded_hal_async::spi::{ErrorType, Operation, SpiDevice};
use remodaq_8318::ad7124::reg;

#[derive(Default)]
pub struct FakeChip {
    pub regs: HashMap<u8, u32>,
    /// Input voltage per pair, mV; `None` = open.
    pub inputs: [Option<f64>; 8],
    /// Every register write, in order.
    pub writes: Vec<(u8, u32)>,
    pub resets: usize,
    /// Conversions that never finish (a dead chip).
    pub stuck: bool,
    /// The next this many conversions never finish, then the chip works again.
    pub stuck_for: usize,
    /// When the last reset began: for 2 ms the chip is in reset (POR_FLAG reads 1 and
    /// writes are lost), as the datasheet describes.
    pub reset_at: Option<embassy_time::Instant>,
    /// A register that does not keep what is written to it (a faulty bus or chip).
    pub deaf: Option<u8>,
    pub id: u8,
}

impl FakeChip {
    pub fn new() -> Self {
        Self { id: 0x14, ..Self::default() }
    }

    fn in_reset(&self) -> bool {
        self.reset_at.is_some_and(|t| t.elapsed() < embassy_time::Duration::from_millis(2))
    }

    fn reg(&self, addr: u8) -> u32 {
        match addr {
            reg::ID => u32::from(self.id),
            reg::STATUS if self.in_reset() => 0x90,
            reg::STATUS => *self.regs.get(&addr).unwrap_or(&0x80),
            _ => *self.regs.get(&addr).unwrap_or(&0),
        }
    }

    fn convert(&mut self) {
        let channel = self.reg(reg::CHANNEL_0);
        let setup = ((channel >> 12) & 7) as u8;
        let ainp = ((channel >> 5) & 0x1F) as usize;
        let ainm = (channel & 0x1F) as usize;
        assert!(channel & 0x8000 != 0, "channel enabled");
        assert_eq!(ainm, ainp + 1, "differential pair");
        let config = self.reg(reg::CONFIG_0 + setup);
        assert!(config & (1 << 11) != 0, "bipolar");
        assert_eq!((config >> 3) & 3, 0b10, "internal reference");
        let gain = 1u32 << (config & 7);
        let burnout = (config >> 9) & 3;
        let (code, error) = match (self.inputs[ainp / 2], burnout) {
            (None, 0) => (0x80_0123, false), // floating: some small reading
            (None, _) => (0xFF_FFFF, true),  // pulled to positive full scale, saturated
            (Some(mv), _) => {
                let x = (mv * f64::from(gain) / 2500.0 * 8_388_608.0 + 8_388_608.0).round();
                let saturated = !(0.0..=16_777_215.0).contains(&x);
                (x.clamp(0.0, 16_777_215.0) as u32, saturated)
            }
        };
        self.regs.insert(reg::DATA, code);
        self.regs.insert(reg::STATUS, if error { 0x40 } else { 0 });
    }
}

impl ErrorType for FakeChip {
    type Error = core::convert::Infallible;
}

impl SpiDevice for FakeChip {
    async fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), Self::Error> {
        match operations {
            [Operation::Write(bytes)] if bytes.iter().all(|b| *b == 0xFF) && bytes.len() == 8 => {
                self.resets += 1;
                self.regs.clear();
                // Reset values (datasheet register map): FILTER_n 060180h.
                for f in 0..8 {
                    self.regs.insert(reg::FILTER_0 + f, 0x06_0180);
                }
                self.reset_at = Some(embassy_time::Instant::now());
            }
            [Operation::Write(bytes)] => {
                let addr = bytes[0] & 0x3F;
                assert_eq!(bytes[0] & 0xC0, 0, "write: WEN and R/W low");
                assert_eq!(bytes.len() - 1, reg::size(addr), "register {addr:#x} size");
                let value = bytes[1..].iter().fold(0u32, |a, b| a << 8 | u32::from(*b));
                self.writes.push((addr, value));
                if self.in_reset() || self.deaf == Some(addr) {
                    return Ok(()); // lost
                }
                self.regs.insert(addr, value);
                if addr == reg::ADC_CONTROL && (value >> 2) & 0xF == 1 {
                    if self.stuck_for > 0 {
                        self.stuck_for -= 1;
                    } else if !self.stuck {
                        self.convert();
                    }
                }
            }
            [Operation::Write([comms]), Operation::Read(buf)] => {
                assert_eq!(*comms & 0xC0, 0x40, "read: R/W high");
                let addr = *comms & 0x3F;
                assert_eq!(buf.len(), reg::size(addr), "register {addr:#x} size");
                let value = self.reg(addr);
                let n = buf.len();
                for (i, b) in buf.iter_mut().enumerate() {
                    *b = (value >> (8 * (n - 1 - i))) as u8;
                }
                if addr == reg::DATA {
                    self.regs.insert(reg::STATUS, 0x80);
                }
            }
            other => panic!("unexpected SPI transaction of {} operations", other.len()),
        }
        Ok(())
    }
}
