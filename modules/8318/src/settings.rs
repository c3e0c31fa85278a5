//! Persisted settings of the 8318 (spec §2.1, §1.4).

use remodaq_shared::access::{self, AllowList};
use remodaq_shared::net::{NetConfig, NetRecord};
use remodaq_shared::password::{self, Credential};
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema};

use crate::input::InputType;

pub use remodaq_protocol::m8318::{cjc_offset_from_register, cjc_offset_to_register, CJC_OFFSET_LIMIT};

/// Everything the 8318 keeps in flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Network settings.
    pub net: NetConfig,
    /// Configuration password: its credential, never the password (docs/security.md).
    pub password: Credential,
    /// Input type code (40201), one of spec §2.2 ([`InputType::from_code`]).
    pub input_type: u8,
    /// CJC offset (40216) in 0.01 °C, within ±[`CJC_OFFSET_LIMIT`].
    pub cjc_offset: i16,
    /// Channel enable mask (40221), bit n = channel n.
    pub enable_mask: u8,
    /// Open-input value (40233, extensions §2): false upscale (FFFFh), true downscale (0000h).
    pub downscale: bool,
    /// Modbus write allow-list (extensions §4).
    pub allow: AllowList,
    /// The web console's TCP port (docs/web.md), in force after a restart.
    pub http_port: u16,
    /// Firmware update security counters (anti-rollback, docs/update.md).
    pub update: remodaq_shared::settings::Counter,
}

mod tag {
    pub const INPUT_TYPE: u8 = 32;
    pub const CJC_OFFSET: u8 = 33;
    pub const ENABLE_MASK: u8 = 34;
    pub const OPEN_VALUE: u8 = 35;
}

impl Schema for Settings {
    // 2: the password as a SCRAM credential (tag 7) instead of a salted hash (docs/security.md).
    const VERSION: u8 = 2;

    fn defaults() -> Self {
        // Decision: factory input type 0Fh (type K), all channels enabled, no CJC offset.
        Self {
            net: NetConfig::FACTORY,
            password: Credential::FACTORY,
            input_type: 0x0F,
            cjc_offset: 0,
            enable_mask: 0xFF,
            downscale: false,
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
        w.put(tag::INPUT_TYPE, &[self.input_type]);
        w.put(tag::CJC_OFFSET, &self.cjc_offset.to_le_bytes());
        w.put(tag::ENABLE_MASK, &[self.enable_mask]);
        w.put(tag::OPEN_VALUE, &[u8::from(self.downscale)]);
        access::encode(&self.allow, w);
        remodaq_shared::net::encode_http_port(self.http_port, w);
        self.update.encode(w);
    }

    fn decode(version: u8, r: &RecordReader<'_>) -> Self {
        let d = Self::defaults();
        Self {
            net: NetConfig::decode(r),
            password: password::decode(version, r),
            input_type: r
                .array::<1>(tag::INPUT_TYPE)
                .map(|[t]| t)
                .filter(|t| InputType::from_code(*t).is_some())
                .unwrap_or(d.input_type),
            cjc_offset: r
                .array(tag::CJC_OFFSET)
                .map(i16::from_le_bytes)
                .filter(|o| o.abs() <= CJC_OFFSET_LIMIT)
                .unwrap_or(d.cjc_offset),
            enable_mask: r.array::<1>(tag::ENABLE_MASK).map(|[m]| m).unwrap_or(d.enable_mask),
            downscale: r.array::<1>(tag::OPEN_VALUE).is_some_and(|[v]| v == 1),
            allow: access::decode(r),
            http_port: remodaq_shared::net::decode_http_port(r),
            update: remodaq_shared::settings::Counter::decode(r),
        }
    }
}

remodaq_shared::impl_common_settings!(Settings);
