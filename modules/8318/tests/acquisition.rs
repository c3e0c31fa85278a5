//! The acquisition cycle and the register map with a fake front end.

use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, NoopRawMutex};
use embassy_sync::mutex::Mutex;
use futures_executor::block_on;
use remodaq_8318::acquisition::{acquire, AnalogFrontEnd, Measurement, Snapshot, CJC_INVALID};
use remodaq_8318::map::Map8318;
use remodaq_8318::settings::Settings;
use remodaq_8318::thermocouple::{Reference, TcType};
use remodaq_shared::modbus::{handle_pdu, MAX_PDU};
use remodaq_shared::ram_flash::RamFlash;
use remodaq_shared::settings::{Schema, SettingsStore};

/// Terminals as the host scenario describes them: mV per channel, open channels, a CJC.
struct Fake {
    mv: [Option<f64>; 8],
    cjc: Result<f64, ()>,
    fail_channel: Option<u8>,
    spans: Vec<(u8, f64, bool)>,
}

impl Fake {
    fn new(cjc: f64) -> Self {
        Self { mv: [Some(0.0); 8], cjc: Ok(cjc), fail_channel: None, spans: Vec::new() }
    }
}

impl AnalogFrontEnd for Fake {
    type Error = &'static str;
    async fn measure(&mut self, channel: u8, span_mv: f64, detect_open: bool) -> Result<Measurement, Self::Error> {
        self.spans.push((channel, span_mv, detect_open));
        if self.fail_channel == Some(channel) {
            return Err("conversion timed out");
        }
        Ok(self.mv[usize::from(channel)].map_or(Measurement::Open, Measurement::Millivolts))
    }
    async fn cold_junction_c(&mut self) -> Result<f64, Self::Error> {
        self.cjc.map_err(|_| "sensor")
    }
}

fn settings(input_type: u8, enable_mask: u8, cjc_offset: i16) -> Settings {
    Settings { input_type, enable_mask, cjc_offset, ..Settings::defaults() }
}

/// Spec §2.2-2.3 as literals: raw = round((x - lo) / (hi - lo) * 65535) on the code's range.
fn expected(code: u8, x: f64) -> u16 {
    let (lo, hi) = match code {
        0x00 => (-15.0, 15.0),
        0x05 => (-2500.0, 2500.0),
        0x06 => (-20.0, 20.0),
        0x0E => (-200.0, 1100.0),
        0x0F => (-250.0, 1400.0),
        other => panic!("no spec range written down here for {other:02X}"),
    };
    ((x - lo) / (hi - lo) * 65535.0).round() as u16
}

#[test]
fn thermocouple_channels_with_cold_junction_compensation() {
    for cjc in [0.0, 21.5, 35.0, -10.0] {
        let mut fe = Fake::new(cjc);
        // Hot junctions at 100, 500 and 1000 °C: the terminals see E(t) - E(t_cj).
        for (ch, t) in [(0usize, 100.0), (1, 500.0), (2, 1000.0)] {
            fe.mv[ch] = Some(TcType::K.emf_mv(t).unwrap() - TcType::K.emf_mv(cjc).unwrap());
        }
        fe.mv[3] = None; // open
        let snap = block_on(acquire(&mut fe, &settings(0x0F, 0xFF, 0)));
        assert_eq!(snap.values[0], expected(0x0F, 100.0), "cjc {cjc}");
        assert_eq!(snap.values[1], expected(0x0F, 500.0), "cjc {cjc}");
        assert_eq!(snap.values[2], expected(0x0F, 1000.0), "cjc {cjc}");
        assert_eq!(snap.values[3], 0xFFFF, "open thermocouple");
        assert_eq!(snap.values[4], expected(0x0F, cjc), "0 mV reads the cold junction");
        assert_eq!(snap.cjc, (cjc * 100.0) as i16);
        assert!(fe.spans.iter().all(|&(_, span, open)| span == 100.0 && open));
    }
}

#[test]
fn cjc_offset_is_added_to_the_cold_junction() {
    let mut fe = Fake::new(25.0);
    fe.mv[0] = Some(TcType::J.emf_mv(300.0).unwrap() - TcType::J.emf_mv(27.5).unwrap());
    // The sensor reads 25.0 but the terminals are at 27.5: an offset of +2.50 °C corrects it.
    let snap = block_on(acquire(&mut fe, &settings(0x0E, 0x01, 250)));
    assert_eq!(snap.values[0], expected(0x0E, 300.0));
    assert_eq!(snap.cjc, 2750);
    let snap = block_on(acquire(&mut Fake::new(25.0), &settings(0x0E, 0x01, -1234)));
    assert_eq!(snap.cjc, 2500 - 1234);
}

#[test]
fn voltage_and_current_channels_and_edges() {
    let mut fe = Fake::new(25.0);
    fe.mv = [Some(1200.0), Some(-2500.0), Some(2500.0), Some(-3000.0), Some(3000.0), Some(0.0), None, Some(1.0)];
    let snap = block_on(acquire(&mut fe, &settings(0x05, 0xFF, 0)));
    assert_eq!(snap.values[0], expected(0x05, 1200.0));
    assert_eq!(snap.values[1..5], [0x0000, 0xFFFF, 0x0000, 0xFFFF], "min, max, under, over");
    assert_eq!(snap.values[5], 0x8000);
    assert_eq!(snap.values[6], 0xFFFF, "open input");
    assert!(fe.spans.iter().all(|&(_, span, open)| span == 2500.0 && !open));
    // 12 mA through 100 ohm = 1200 mV.
    let mut fe = Fake::new(25.0);
    fe.mv[0] = Some(12.0 * 100.0);
    fe.mv[1] = Some(-20.0 * 100.0);
    let snap = block_on(acquire(&mut fe, &settings(0x06, 0x03, 0)));
    assert_eq!(snap.values[0], expected(0x06, 12.0));
    assert_eq!(snap.values[0], 52428);
    assert_eq!(snap.values[1], 0);
}

#[test]
fn disabled_channels_read_zero_and_are_not_converted() {
    let mut fe = Fake::new(25.0);
    fe.mv = [Some(5.0); 8];
    let snap = block_on(acquire(&mut fe, &settings(0x00, 0b1010_0101, 0)));
    for ch in 0..8 {
        if 0b1010_0101 & (1 << ch) == 0 {
            assert_eq!(snap.values[ch], 0, "channel {ch}");
        } else {
            assert_eq!(snap.values[ch], expected(0x00, 5.0));
        }
    }
    assert_eq!(fe.spans.iter().map(|s| s.0).collect::<Vec<_>>(), vec![0, 2, 5, 7]);
}

#[test]
fn front_end_failures() {
    let mut fe = Fake::new(25.0);
    fe.fail_channel = Some(2);
    fe.cjc = Err(());
    let snap = block_on(acquire(&mut fe, &settings(0x0F, 0x0F, 0)));
    assert_eq!(snap.cjc, CJC_INVALID);
    assert_eq!(snap.values[..4], [0xFFFF; 4], "no cold junction: thermocouples unknown");
    let mut fe = Fake::new(25.0);
    fe.fail_channel = Some(2);
    fe.cjc = Err(());
    let snap = block_on(acquire(&mut fe, &settings(0x04, 0x0F, 0)));
    assert_eq!(snap.values[..4], [0x8000, 0x8000, 0xFFFF, 0x8000], "voltages need no cold junction");
}

#[test]
fn thermocouple_outside_the_reference_function() {
    // Type K is defined to 1372 °C, its module range goes to 1400 °C: above 1372 clamps high.
    let mut fe = Fake::new(0.0);
    fe.mv[0] = Some(TcType::K.emf_mv(1372.0).unwrap() + 0.5);
    fe.mv[1] = Some(TcType::K.emf_mv(-270.0).unwrap() - 0.5);
    fe.mv[2] = Some(TcType::K.emf_mv(-260.0).unwrap());
    let snap = block_on(acquire(&mut fe, &settings(0x0F, 0x07, 0)));
    assert_eq!(snap.values[..3], [0xFFFF, 0x0000, 0x0000]);
}

#[test]
fn map_publishes_a_whole_cycle() {
    type Flash = RamFlash<{ 4 * 1024 }, 1024>;
    block_on(async {
        let store = SettingsStore::<Flash, Settings>::open(
            Flash::new(),
            const { SettingsStore::<Flash, Settings>::config(0..4096) },
        )
        .await;
        let settings = *store.get();
        let store = Mutex::<CriticalSectionRawMutex, _>::new(store);
        let map = Mutex::<NoopRawMutex, _>::new(Map8318::new(&store, &settings));
        let mut resp = [0u8; MAX_PDU];
        let n = handle_pdu(&map, [127, 0, 0, 1], &[0x04, 0x00, 0x00, 0x00, 0x09], &mut resp).await;
        assert_eq!(&resp[..n], &[0x04, 18, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        map.lock().await.publish(Snapshot { values: [1, 2, 3, 4, 5, 6, 7, 0xFFFF], cjc: -1234, ..Snapshot::default() });
        let n = handle_pdu(&map, [127, 0, 0, 1], &[0x03, 0x00, 0x00, 0x00, 0x09], &mut resp).await;
        assert_eq!(&resp[..n], &[0x03, 18, 0, 1, 0, 2, 0, 3, 0, 4, 0, 5, 0, 6, 0, 7, 0xFF, 0xFF, 0xFB, 0x2E]);
        // 40010 is not mapped.
        let n = handle_pdu(&map, [127, 0, 0, 1], &[0x03, 0x00, 0x00, 0x00, 0x0A], &mut resp).await;
        assert_eq!(&resp[..n], &[0x83, 0x02]);
        // Channel values are read only.
        let n = handle_pdu(&map, [127, 0, 0, 1], &[0x06, 0x00, 0x00, 0x00, 0x01], &mut resp).await;
        assert_eq!(&resp[..n], &[0x86, 0x02]);
    });
}
