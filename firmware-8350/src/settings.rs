//! Persisted settings of the 8350 (spec §3.5, §1.4). The I/O settings join with the DI/DO engine.

use remodaq_shared::net::NetConfig;
use remodaq_shared::settings::{RecordReader, RecordWriter, Schema};

/// Everything the 8350 keeps in flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// Network settings.
    pub net: NetConfig,
}

impl Schema for Settings {
    const VERSION: u8 = 1;

    fn defaults() -> Self {
        Self { net: NetConfig::FACTORY }
    }

    fn encode(&self, w: &mut RecordWriter<'_>) {
        self.net.encode(w);
    }

    fn decode(_version: u8, r: &RecordReader<'_>) -> Self {
        Self { net: NetConfig::decode(r) }
    }
}
