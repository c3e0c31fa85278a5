//! Persisted settings of the 8350 (spec §3.5, §1.4): DI modes, DO modes, pulse widths and
//! counts, network settings. Counters, run bits, flags and output states are not persisted.

use remodaq_protocol::m8350::{wd_mode, DO_CHANNELS, WD_TIMEOUT_MAX};
use remodaq_shared::access::{self, AllowList};
use remodaq_shared::net::{NetConfig, NetRecord};
use remodaq_shared::password::{self, Credential};
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema};

use crate::di::{self, DiMode};
use crate::pulse::{self, DoMode, PulseConfig};
use crate::watchdog::WatchdogConfig;

/// Everything the 8350 keeps in flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Network settings.
    pub net: NetConfig,
    /// Configuration password: its credential, never the password (docs/security.md).
    pub password: Credential,
    /// DI n mode (40257 + n).
    pub di_modes: [DiMode; di::CHANNELS],
    /// DO n mode (40273 + n).
    pub do_modes: [DoMode; pulse::CHANNELS],
    /// DO n pulse widths and count (40025.., 40037.., 40049..).
    pub pulses: [PulseConfig; pulse::CHANNELS],
    /// Host watchdog timeout and mode (40305, 40307).
    pub watchdog: WatchdogConfig,
    /// Safe output values, bit n = DOn (40306).
    pub safe: u8,
    /// Power-on output values, bit n = DOn (40309).
    pub power_on: u8,
    /// Modbus write allow-list (extensions §4).
    pub allow: AllowList,
    /// The web console's TCP port (docs/web.md), in force after a restart.
    pub http_port: u16,
    /// Firmware update security counters (anti-rollback, docs/update.md).
    pub update: remodaq_shared::settings::Counter,
}

/// Whether `v` is a valid output-values register (bits 6-15 zero).
pub fn output_values(v: u16) -> Option<u8> {
    (v >> DO_CHANNELS == 0).then_some(v as u8)
}

/// Whether `v` is a valid watchdog timeout (0..=6000).
pub fn watchdog_timeout(v: u16) -> Option<u16> {
    (v <= WD_TIMEOUT_MAX).then_some(v)
}

/// Whether `v` is a valid watchdog mode (bits 2-15 zero).
pub fn watchdog_mode(v: u16) -> Option<u16> {
    (v & !wd_mode::ALL == 0).then_some(v)
}

mod tag {
    pub const DI_MODES: u8 = 32;
    pub const DO_MODES: u8 = 33;
    pub const LOW: u8 = 34;
    pub const HIGH: u8 = 35;
    pub const COUNT: u8 = 36;
    pub const WD_TIMEOUT: u8 = 37;
    pub const WD_MODE: u8 = 38;
    pub const SAFE: u8 = 39;
    pub const POWER_ON: u8 = 40;
}

fn put_u32s(w: &mut RecordWriter<'_>, tag: u8, values: impl Iterator<Item = u32>) {
    let mut bytes = [0u8; 4 * pulse::CHANNELS];
    for (chunk, v) in bytes.chunks_exact_mut(4).zip(values) {
        chunk.copy_from_slice(&v.to_le_bytes());
    }
    w.put(tag, &bytes);
}

fn get_u32s(r: &RecordReader<'_>, tag: u8) -> Option<[u32; pulse::CHANNELS]> {
    let bytes: [u8; 4 * pulse::CHANNELS] = r.array(tag)?;
    let mut out = [0u32; pulse::CHANNELS];
    for (v, chunk) in out.iter_mut().zip(bytes.chunks_exact(4)) {
        *v = u32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
    }
    Some(out)
}

impl Schema for Settings {
    // 2: the password as a SCRAM credential (tag 7) instead of a salted hash (docs/security.md).
    const VERSION: u8 = 2;

    fn defaults() -> Self {
        Self {
            net: NetConfig::FACTORY,
            password: Credential::FACTORY,
            di_modes: [DiMode::Normal; di::CHANNELS],
            do_modes: [DoMode::Normal; pulse::CHANNELS],
            pulses: [PulseConfig::default(); pulse::CHANNELS],
            watchdog: WatchdogConfig::default(),
            safe: 0,
            power_on: 0,
            allow: AllowList::EMPTY,
            http_port: remodaq_shared::net::HTTP_PORT,
            update: remodaq_shared::settings::Counter::default(),
        }
    }

    /// The factory defaults with the credential locked (docs/security.md: fails closed).
    fn unreadable() -> Self {
        Self { password: remodaq_shared::password::LOCKED, ..Self::defaults() }
    }

    fn encode(&self, w: &mut RecordWriter<'_>) {
        self.net.encode(w);
        password::encode(&self.password, w);
        w.put(tag::DI_MODES, &self.di_modes.map(|m| m as u8));
        w.put(tag::DO_MODES, &self.do_modes.map(|m| m as u8));
        put_u32s(w, tag::LOW, self.pulses.iter().map(|p| p.low));
        put_u32s(w, tag::HIGH, self.pulses.iter().map(|p| p.high));
        put_u32s(w, tag::COUNT, self.pulses.iter().map(|p| p.count));
        w.put_u16(tag::WD_TIMEOUT, self.watchdog.timeout);
        w.put_u16(tag::WD_MODE, self.watchdog.mode);
        w.put(tag::SAFE, &[self.safe]);
        w.put(tag::POWER_ON, &[self.power_on]);
        access::encode(&self.allow, w);
        remodaq_shared::net::encode_http_port(self.http_port, w);
        self.update.encode(w);
    }

    fn decode(version: u8, r: &RecordReader<'_>) -> Self {
        let mut s = Self::defaults();
        s.net = NetConfig::decode(r);
        s.password = password::decode(version, r);
        if let Some(modes) = r.array::<{ di::CHANNELS }>(tag::DI_MODES) {
            for (m, v) in s.di_modes.iter_mut().zip(modes) {
                *m = DiMode::from_register(u16::from(v)).unwrap_or(DiMode::Normal);
            }
        }
        if let Some(modes) = r.array::<{ pulse::CHANNELS }>(tag::DO_MODES) {
            for (m, v) in s.do_modes.iter_mut().zip(modes) {
                *m = DoMode::from_register(u16::from(v)).unwrap_or(DoMode::Normal);
            }
        }
        let d = PulseConfig::default();
        let (low, high, count) = (get_u32s(r, tag::LOW), get_u32s(r, tag::HIGH), get_u32s(r, tag::COUNT));
        for (n, p) in s.pulses.iter_mut().enumerate() {
            p.low = low.map(|v| v[n]).filter(|w| *w >= 1).unwrap_or(d.low);
            p.high = high.map(|v| v[n]).filter(|w| *w >= 1).unwrap_or(d.high);
            p.count = count.map_or(d.count, |v| v[n]);
        }
        s.watchdog.timeout = r.u16(tag::WD_TIMEOUT).and_then(watchdog_timeout).unwrap_or(0);
        s.watchdog.mode = r.u16(tag::WD_MODE).and_then(watchdog_mode).unwrap_or(0);
        let values = |tag| r.array::<1>(tag).and_then(|[v]| output_values(u16::from(v))).unwrap_or(0);
        s.safe = values(tag::SAFE);
        s.power_on = values(tag::POWER_ON);
        s.allow = access::decode(r);
        s.http_port = remodaq_shared::net::decode_http_port(r);
        s.update = remodaq_shared::settings::Counter::decode(r);
        s
    }
}

remodaq_shared::impl_common_settings!(Settings);
