//! The 8350's digital I/O on this board, both paced by hardware timers so that timing never
//! depends on when a task runs:
//!
//! - Inputs DI0-DI11 on PE2-PE13 (pull-down). TIM1's update event, 50 000 times a second,
//!   triggers DMA2 stream 5 (channel 6) to copy GPIOE's input register into a 4096-sample
//!   circular buffer (82 ms); the input task drains it every few ms. Edges are lost only if the
//!   task falls 82 ms behind, and that is detected and logged (overrun).
//! - Outputs DO0-DO5 on PF12, PF13, PF14, PF15, PF3, PF5. TIM8's update event, 10 000 times a
//!   second (the pulse engine's 0.1 ms tick), triggers DMA2 stream 1 (channel 7) to copy one
//!   word per tick from a 128-tick circular pattern into GPIOF's set/reset register; the output
//!   task writes a chunk (half the ring) as soon as one has played, timed from the ticks queued. A 5 kHz train is exact however busy the CPU is. An
//!   output command is written into the queued words from 3 ticks after the DMA's position
//!   (read from NDTR), so it reaches the pin 0.3-0.4 ms after the output task runs. The margin
//!   against the DMA is at least 0.2 ms, not 0.3: in direct mode the stream has already fetched
//!   the word at NDTR before its request (RM0090 §10.3.11, "Direct mode"), so that word is
//!   spent; the latency counted from NDTR under-reports by up to one tick (stm32 review N1).

use core::cell::UnsafeCell;

use embassy_stm32::dma::{Channel, ReadableRingBuffer, Transfer, TransferOptions};
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::peripherals::{DMA2_CH1, DMA2_CH5, TIM1, TIM8};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::{RoundTo, Timer};
use embassy_stm32::{bind_interrupts, dma, pac};
use embassy_time::Instant;
use remodaq_8350::di::SAMPLE_RATE_HZ;
use remodaq_8350::io::{InputCapture, OutputPattern, PatternUnderrun, SamplesLost, FORCE_AHEAD, OUTPUT_CHUNK};
use remodaq_8350::pulse::TICK_HZ;
use remodaq_8350::ring::DmaPosition;
use remodaq_8350::M8350;
use remodaq_shared::board::IoFor;
use static_cell::StaticCell;

use crate::resources::{DigitalPeripherals, Io};
use crate::Stm32Board;

bind_interrupts!(struct Irqs {
    DMA2_STREAM5 => dma::InterruptHandler<DMA2_CH5>;
    DMA2_STREAM1 => dma::InterruptHandler<DMA2_CH1>;
});

/// Capture ring, samples (82 ms at the module's 50 kHz).
const CAPTURE_LEN: usize = remodaq_8350::io::CAPTURE_RING;
/// Output pattern ring, ticks: two of the module's refill chunks.
const PATTERN_LEN: usize = 2 * OUTPUT_CHUNK;
/// DMA request (channel selection) of TIM1_UP on DMA2 stream 5, TIM8_UP on DMA2 stream 1.
const TIM1_UP_REQUEST: u8 = 6;
const TIM8_UP_REQUEST: u8 = 7;
/// GPIOF bit of DO n.
const DO_PINS: [u8; 6] = [12, 13, 14, 15, 3, 5];
/// GPIOE bit of DI0.
const DI_SHIFT: u16 = 2;

/// The running input capture.
pub struct Capture {
    ring: ReadableRingBuffer<'static, u16>,
    _pins: [Input<'static>; 12],
    _timer: Timer<'static, TIM1>,
}

impl InputCapture for Capture {
    fn read(&mut self, out: &mut [u16]) -> Result<usize, SamplesLost> {
        match self.ring.read(out) {
            Ok((n, _)) => {
                for s in &mut out[..n] {
                    *s = (*s >> DI_SHIFT) & 0x0FFF;
                }
                Ok(n)
            }
            Err(_) => {
                self.ring.clear();
                Err(SamplesLost)
            }
        }
    }
}

/// The running output pattern.
pub struct Pattern {
    /// The circular transfer of the pattern into GPIOF's BSRR, for as long as the module runs
    /// (dropping it would stop the stream).
    transfer: Transfer<'static>,
    /// The pattern's words ([`PATTERN`]): read by the DMA, written only through this pointer.
    words: *mut u32,
    /// Ticks written since the start: the next goes at `written % PATTERN_LEN`.
    written: u64,
    /// Whether a tick was written yet (the first write starts after the DMA's place).
    started: bool,
    /// Where the DMA stands, in ticks since the start.
    dma: DmaPosition,
    _pins: [Output<'static>; 6],
    _timer: Timer<'static, TIM8>,
}

// SAFETY: `words` points to the 'static pattern this value alone writes (the DMA reads it; no
// reference to it exists); moving the pattern to the realtime executor's interrupt moves that
// ownership with it.
unsafe impl Send for Pattern {}

/// The output pattern's words: DMA2 reads them (in SRAM, checked at link time, memory.x), this
/// board writes them through a raw pointer only ([`Pattern::words`]), never through a reference,
/// so the two never alias a `&mut` (stm32 review R1: embassy's ring buffer held a `&mut` to them
/// while `force` wrote through a pointer).
struct PatternWords(UnsafeCell<[u32; PATTERN_LEN]>);

// SAFETY: only `DigitalPeripherals::start`, which runs once (it consumes the peripherals),
// takes the pointer; every access through it is volatile, by the one `Pattern`.
unsafe impl Sync for PatternWords {}

#[unsafe(export_name = "REMODAQ_DMA_PATTERN")]
static PATTERN: PatternWords = PatternWords(UnsafeCell::new([0; PATTERN_LEN]));

/// The set/reset bits of the DOs in `mask` (bit n = DOn): both halves of each pin.
fn bsrr_pins(mask: u8) -> u32 {
    DO_PINS.iter().enumerate().filter(|(n, _)| mask >> n & 1 == 1).fold(0, |word, (_, pin)| word | 0x1_0001 << pin)
}

/// The set/reset word of one tick's levels (bit n = DOn).
fn bsrr(levels: u8) -> u32 {
    DO_PINS.iter().enumerate().fold(
        0,
        |word, (n, pin)| {
            if levels >> n & 1 == 1 {
                word | 1 << pin
            } else {
                word | 1 << (pin + 16)
            }
        },
    )
}

impl Pattern {
    /// The tick the DMA reads next, in ticks since the start.
    fn playing(&mut self) -> u64 {
        let remaining = self.transfer.get_remaining_transfers() as usize;
        self.dma.sync(remaining, Instant::now().as_micros())
    }

    /// Ticks queued and not played yet, or `None` when the DMA has gone past the last tick
    /// written (it plays old ticks again).
    fn queued(&mut self) -> Option<u64> {
        let playing = self.playing();
        self.written.checked_sub(playing)
    }

    /// Writes tick `k` (since the start) as `word`: a volatile write through the pattern's
    /// pointer.
    fn put(&mut self, k: u64, word: impl FnOnce(u32) -> u32) {
        let i = (k % PATTERN_LEN as u64) as usize;
        // SAFETY: `words` is the 'static pattern of PATTERN_LEN words, i is below PATTERN_LEN,
        // and no reference to those words exists (`PatternWords`); the DMA only reads them.
        unsafe {
            let at = self.words.add(i);
            at.write_volatile(word(at.read_volatile()));
        }
    }
}

impl OutputPattern for Pattern {
    async fn room(&mut self) {
        // Until the DMA has played enough for a chunk: the moment is known from the ticks
        // queued (the pattern plays at exactly TICK_HZ), so a timer waits for it, wherever the
        // chunks' ends fall in the ring (a refill after running dry starts anywhere).
        loop {
            let wait = match self.queued() {
                Some(queued) => (queued + OUTPUT_CHUNK as u64).saturating_sub(PATTERN_LEN as u64),
                // Run dry: `write` reports it.
                None => 0,
            };
            if wait == 0 {
                return;
            }
            embassy_time::Timer::after_micros(wait * 1_000_000 / u64::from(TICK_HZ)).await;
        }
    }

    fn write(&mut self, levels: &[u8]) -> Result<u32, PatternUnderrun> {
        let playing = self.playing();
        // The word at the DMA's place is read already (direct mode fetches it ahead, RM0090
        // §10.3.11): a refill that starts there is late too.
        let dry = playing >= self.written && self.started;
        if playing >= self.written || !self.started {
            // From a few ticks after the DMA's place: the first write, or after the pattern ran
            // dry (the DMA played old ticks meanwhile; the host and QEMU boards' simulated rings
            // write from the tick playing, which no DMA has fetched ahead there).
            self.written = playing + u64::from(FORCE_AHEAD);
            self.started = true;
        }
        let ahead = self.written - playing;
        // Never over a tick not played yet.
        let n = levels.len().min((PATTERN_LEN as u64).saturating_sub(ahead) as usize);
        for &l in &levels[..n] {
            let k = self.written;
            self.put(k, |_| bsrr(l));
            self.written += 1;
        }
        if dry {
            Err(PatternUnderrun)
        } else {
            Ok(ahead as u32)
        }
    }

    fn force(&mut self, mask: u8, levels: u8) -> u32 {
        let playing = self.playing();
        let Some(queued) = self.written.checked_sub(playing) else { return 0 };
        let ahead = u64::from(FORCE_AHEAD);
        if queued <= ahead {
            return queued as u32;
        }
        // From FORCE_AHEAD ticks after the DMA's place (NDTR, RM0090 §10.3.9 "Circular mode",
        // §10.5.6 DMA_SxNDTR; at least 0.2 ms given the word the stream has prefetched) to the
        // last tick written: queued, not read by the DMA yet.
        let pins = bsrr_pins(mask);
        let new = bsrr(levels) & pins;
        for k in playing + ahead..self.written {
            self.put(k, |word| (word & !pins) | new);
        }
        // Interrupts stay on: if the DMA moved past the margin meanwhile, a tick or more
        // played the old level between new ones. Said, not hidden.
        let moved = self.playing() - playing;
        if moved >= ahead {
            remodaq_shared::warn!("outputs: a forced rewrite outran its margin ({} ticks)", moved);
        }
        FORCE_AHEAD
    }
}

impl IoFor<M8350> for Stm32Board {
    type Io = (Capture, Pattern);

    fn io(resources: Io) -> (Capture, Pattern) {
        resources.digital.start()
    }
}

impl DigitalPeripherals {
    /// Starts capture and output; the pattern starts with every output off (spec §3.4).
    pub fn start(self) -> (Capture, Pattern) {
        let pins = self.di.map(|pin| Input::new(pin, Pull::Down));
        // DMA2 writes it: in SRAM, checked at link time (memory.x).
        #[unsafe(export_name = "REMODAQ_DMA_CAPTURE")]
        static CAPTURE: StaticCell<[u16; CAPTURE_LEN]> = StaticCell::new();
        let buffer = CAPTURE.init([0; CAPTURE_LEN]);
        // SAFETY: GPIOE's input register is a valid, always-readable peripheral address; the
        // buffer is 'static and owned by the ring from here on.
        let mut ring = unsafe {
            ReadableRingBuffer::new(
                Channel::new(self.dma_in, Irqs),
                TIM1_UP_REQUEST,
                pac::GPIOE.idr().as_ptr() as *mut u16,
                buffer,
                TransferOptions::default(),
            )
        };
        ring.start();
        let timer = Timer::new(self.tim_in);
        timer.set_frequency(Hertz(SAMPLE_RATE_HZ), RoundTo::Slower);
        timer.enable_update_dma(true);
        timer.start();
        let capture = Capture { ring, _pins: pins, _timer: timer };

        let outputs = self.outputs.map(|pin| Output::new(pin, Level::Low, Speed::High));
        // Every output off in every tick until the first write.
        let words = PATTERN.0.get() as *mut u32;
        for i in 0..PATTERN_LEN {
            // SAFETY: the pattern's 'static words, i below PATTERN_LEN; the DMA is not started.
            unsafe { words.add(i).write_volatile(bsrr(0)) };
        }
        static CHANNEL: StaticCell<Channel<'static>> = StaticCell::new();
        let channel = CHANNEL.init(Channel::new(self.dma_out, Irqs));
        let mut options = TransferOptions::default();
        // No interrupt: the output task times its refills from the ticks queued (`room`).
        options.circular = true;
        options.half_transfer_ir = false;
        options.complete_transfer_ir = false;
        // SAFETY: GPIOF's set/reset register is a valid, write-only peripheral address whose
        // writes only change the pins of its set bits; the pattern is 'static, in SRAM, and
        // reached by the CPU only through `words`, by volatile accesses.
        let transfer = unsafe {
            channel.write_raw(
                TIM8_UP_REQUEST,
                core::ptr::slice_from_raw_parts(words as *const u32, PATTERN_LEN),
                pac::GPIOF.bsrr().as_ptr() as *mut u32,
                options,
            )
        };
        let dma = DmaPosition::new(PATTERN_LEN, Instant::now().as_micros());
        let timer = Timer::new(self.tim_out);
        timer.set_frequency(Hertz(TICK_HZ), RoundTo::Slower);
        timer.enable_update_dma(true);
        timer.start();
        let pattern = Pattern { transfer, words, written: 0, started: false, dma, _pins: outputs, _timer: timer };
        (capture, pattern)
    }
}
