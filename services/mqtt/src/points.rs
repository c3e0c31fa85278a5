//! A module's points as MQTT publishes them (docs/mqtt.md, "What is published"), read from its
//! register map as the web console's API reads them (`remodaq_shared::points`: the same numbers
//! as a Modbus read of the same registers), and its output commands carried out through that
//! map as a Modbus master's writes would be.

use core::fmt::Write as _;

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::Duration;
use remodaq_protocol::m8318::{self, InputType};
use remodaq_protocol::resources::{self, Format, Resource};
use remodaq_protocol::Table;
use remodaq_shared::modbus::pdu::{check_write, handle_pdu, MAX_PDU};
use remodaq_shared::modbus::RegisterMap;
use remodaq_shared::points::{engineering_thousandths, json_value, seen, Seen};

use crate::command::Command;
use crate::session::{Module, Payload, PointTopic, Reading, Refused};
use crate::topics::Kind;

/// An 8318 channel's status as published (spec's status codes, in order): ok, open, over,
/// under, and the module's own.
const STATUS: [&str; 7] = ["ok", "open", "over", "under", "disabled", "fault", "cjc fault"];

/// The cold junction's deadband, thousandths of a °C (its register has hundredths).
const CJC_DEADBAND: u64 = 100;

/// What the publication needs to know beyond the map.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// The 8318's deadbands per channel, thousandths of the channel's unit.
    pub deadbands: [u32; m8318::CHANNELS],
    /// The 8350's points published on any change (else on the period alone).
    pub on_change: bool,
    /// The broker's address: the source of the commands as the map's admission sees it (the
    /// Modbus allow-list applies to it).
    pub broker: [u8; 4],
}

/// The module's side of a session over its register map.
pub struct MapModule<'a, R: RawMutex, M: RegisterMap> {
    /// The register map, as the Modbus server shares it.
    pub map: &'a Mutex<R, M>,
    /// The module's model (`0x8318`, `0x8350`).
    pub model: u16,
    /// Its firmware version and MAC, for `online`.
    pub firmware: u16,
    /// Its MAC.
    pub mac: [u8; 6],
    /// Seconds since start, for `online`.
    pub uptime_s: fn() -> u64,
    /// Milliseconds since 1970 (SNTP), or `None` before a time.
    pub time_ms: fn() -> Option<u64>,
    /// The publication's options.
    pub options: Options,
    /// What [`Module::read`] read last, for [`Module::payload`].
    pub last: Last,
}

/// The registers a point's reading was taken from, kept until its payload is written (a point
/// that is not due is read, never formatted).
#[derive(Clone, Debug, Default)]
pub enum Last {
    /// Nothing read yet.
    #[default]
    None,
    /// The 8318's cold junction, hundredths of a °C.
    Cjc(i16),
    /// An 8318 channel: its code, status and input type.
    Ai {
        /// The channel's resource.
        r: &'static Resource,
        /// Its raw code.
        raw: u16,
        /// Its status code.
        status: u16,
        /// The input type in force.
        input: Option<InputType>,
    },
    /// An 8350 item: its shown fields as read.
    Item {
        /// The item's resource.
        r: &'static Resource,
        /// Each shown field's value.
        values: heapless::Vec<Seen, 8>,
    },
}

/// Which point `i` is: a resource's item, or the 8318's cold junction.
enum Which {
    Item(&'static Resource, Kind, u16),
    Cjc,
}

impl<R: RawMutex, M: RegisterMap> MapModule<'_, R, M> {
    fn which(&self, i: usize) -> Which {
        let of = |name: &str| resources::of(self.model).iter().find(|r| r.name == name);
        let i = i as u16;
        if self.model == 0x8318 {
            match of("channels") {
                Some(r) if i < r.count => Which::Item(r, Kind::Ai, i),
                _ => Which::Cjc,
            }
        } else {
            match (of("di"), of("do")) {
                (Some(di), _) if i < di.count => Which::Item(di, Kind::Di, i),
                (Some(di), Some(o)) => Which::Item(o, Kind::Do, (i - di.count).min(o.count.saturating_sub(1))),
                _ => Which::Cjc,
            }
        }
    }

    fn time(&self, payload: &mut Payload) {
        let _ = match (self.time_ms)() {
            Some(ms) => write!(payload, "\"time\":{ms}"),
            None => write!(payload, "\"time\":null"),
        };
    }
}

impl<R: RawMutex, M: RegisterMap> Module for MapModule<'_, R, M> {
    fn points(&self) -> usize {
        let count = |name: &str| resources::of(self.model).iter().find(|r| r.name == name).map_or(0, |r| r.count);
        usize::from(if self.model == 0x8318 { count("channels") + 1 } else { count("di") + count("do") })
    }

    fn tick(&self) -> Duration {
        // The 8318 acquires every 100 ms: a change reaches MQTT within one cycle. The 8350's
        // inputs change at any moment: within 20 ms (issue #40).
        Duration::from_millis(if self.model == 0x8318 { 50 } else { 10 })
    }

    async fn read(&mut self, i: usize) -> Reading {
        match self.which(i) {
            Which::Cjc => {
                let h = self.map.lock().await.observe(Table::Registers, m8318::REG_CJC) as i16;
                self.last = Last::Cjc(h);
                Reading { topic: PointTopic::Leaf("cjc"), value: i64::from(h) * 10, status: 0, deadband: CJC_DEADBAND }
            }
            Which::Item(r, Kind::Ai, n) => {
                let (raw, status, input) = {
                    let mut map = self.map.lock().await;
                    let raw = map.observe(Table::Registers, m8318::REG_VALUE + n);
                    let status = map.observe(Table::Registers, m8318::REG_STATUS + n);
                    let input = InputType::from_code(map.observe(Table::Registers, m8318::REG_INPUT_TYPE) as u8);
                    (raw, status, input)
                };
                let value = input.as_ref().map(|t| engineering_thousandths(t, raw));
                self.last = Last::Ai { r, raw, status, input };
                let deadband = u64::from(self.options.deadbands.get(usize::from(n)).copied().unwrap_or(0));
                Reading {
                    topic: PointTopic::Numbered(Kind::Ai, n as u8),
                    value: value.unwrap_or(0),
                    status: status as u8,
                    deadband,
                }
            }
            Which::Item(r, kind, n) => {
                // The item's shown fields, as the web console's API shows them; its value for the
                // schedule is a fingerprint of them all (any change is a change).
                let mut values: heapless::Vec<Seen, 8> = heapless::Vec::new();
                {
                    let mut map = self.map.lock().await;
                    for f in r.fields.iter().filter(|f| f.shown) {
                        let _ = values.push(seen(&mut *map, f, n));
                    }
                }
                let mut fingerprint: u64 = 0xcbf2_9ce4_8422_2325;
                for v in &values {
                    let word = match *v {
                        Seen::Unmapped => continue,
                        Seen::Null => u64::MAX,
                        Seen::Value(v) => u64::from(v),
                    };
                    fingerprint = (fingerprint ^ word).wrapping_mul(0x0000_0100_0000_01b3);
                }
                self.last = Last::Item { r, values };
                let deadband = if self.options.on_change { 0 } else { u64::MAX };
                Reading { topic: PointTopic::Numbered(kind, n as u8), value: fingerprint as i64, status: 0, deadband }
            }
        }
    }

    fn payload(&self, payload: &mut Payload) {
        payload.clear();
        match &self.last {
            Last::None => return,
            Last::Cjc(h) => {
                let sign = if *h < 0 { "-" } else { "" };
                let _ = write!(
                    payload,
                    "{{\"value\":{sign}{}.{:02},\"unit\":\"°C\",",
                    h.unsigned_abs() / 100,
                    h.unsigned_abs() % 100
                );
            }
            Last::Ai { r, raw, status, input } => {
                let _ = payload.push_str("{\"value\":");
                if let Some(f) = r.fields.iter().find(|f| f.format == Format::Engineering) {
                    json_value(payload, f, u32::from(*raw), input.as_ref());
                }
                let unit = input.as_ref().map_or("", resources::unit);
                let name = STATUS.get(usize::from(*status)).copied().unwrap_or("fault");
                let _ = write!(payload, ",\"unit\":\"{unit}\",\"status\":\"{name}\",\"raw\":{raw},");
            }
            Last::Item { r, values } => {
                let _ = payload.push('{');
                for (f, v) in r.fields.iter().filter(|f| f.shown).zip(values) {
                    match *v {
                        Seen::Unmapped => {}
                        Seen::Null => {
                            let _ = write!(payload, "\"{}\":null,", f.name);
                        }
                        Seen::Value(v) => {
                            let _ = write!(payload, "\"{}\":", f.name);
                            json_value(payload, f, v, None);
                            let _ = payload.push(',');
                        }
                    }
                }
            }
        }
        self.time(payload);
        let _ = payload.push('}');
    }

    fn online(&self, payload: &mut Payload) {
        let mut digits = [0u8; 12];
        let mac = remodaq_protocol::web::hex(&self.mac, &mut digits).unwrap_or("");
        let _ = write!(
            payload,
            "{{\"state\":\"online\",\"model\":\"{:04X}\",\"firmware\":\"{:04X}\",\"mac\":\"{mac}\",\"uptime_s\":{}}}",
            self.model,
            self.firmware,
            (self.uptime_s)()
        );
    }

    fn outputs(&self) -> u8 {
        resources::of(self.model).iter().find(|r| r.name == "do").map_or(0, |r| r.count as u8)
    }

    async fn command(&mut self, n: u8, command: Command) -> Result<(), ()> {
        let requests = command.requests(n);
        // All checked before the first is applied: a refused command changes nothing.
        {
            let mut map = self.map.lock().await;
            if requests.iter().any(|r| check_write(&mut *map, self.options.broker, r.bytes()).is_err()) {
                return Err(());
            }
        }
        for r in &requests {
            let mut resp = [0u8; MAX_PDU];
            let len = handle_pdu(self.map, self.options.broker, r.bytes(), &mut resp).await;
            if len < 2 || resp[0] & 0x80 != 0 {
                return Err(());
            }
        }
        Ok(())
    }

    fn refused(&mut self, why: Refused) {
        use remodaq_shared::diagnostics::{mqtt, DIAGNOSTICS};
        DIAGNOSTICS.mqtt_event(match why {
            Refused::Payload(_) => mqtt::MALFORMED,
            Refused::Module => mqtt::REFUSED,
            Refused::NotTaken => mqtt::IGNORED,
        });
    }
}
