//! The named resources of the web console's API (`/api/v1/`, docs/web.md, docs/openapi.yaml):
//! every field is a run of Modbus addresses of this crate's register maps, with the format its
//! value takes in JSON. The module reads and writes them through its register map, as Modbus
//! does, so the API and Modbus cannot disagree; this table is only what names what.

use crate::diag;
use crate::m8318::{self, ChannelStatus};
use crate::m8350;
use crate::Table;

/// How a field's value is shown and written.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Format {
    /// A bit (JSON `true`/`false`).
    Bool,
    /// One register, 0..65535.
    Word,
    /// Two registers, a 32-bit number, low word first (spec §3.2).
    Long,
    /// One register, a signed number of hundredths (the CJC temperature and offset, spec §2.4):
    /// a JSON number with two decimals.
    Hundredths,
    /// One register holding the index of a name (a mode, a status): the name.
    Named(&'static [&'static str]),
    /// Bit `n` (the item's index) of one register (a channel of an enable mask).
    MaskBit,
    /// The 8318's channel value: the register over the input type's range, in engineering
    /// units (spec §2.3).
    Engineering,
    /// The 8318's input type code (spec §2.2): the code and, shown, its type, unit and range.
    InputType,
    /// The 8350's DI frequency: the counter's low word in frequency mode (spec §3.3), else
    /// `null`.
    Frequency,
    /// Two registers holding an IPv4 address, a.b then c.d.
    Ipv4,
}

/// One field of a resource.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Field {
    /// Its JSON name.
    pub name: &'static str,
    /// The table its addresses are in.
    pub table: Table,
    /// The address of item 0.
    pub base: u16,
    /// Addresses from one item to the next (0 for a field of the whole resource).
    pub stride: u16,
    /// Its format.
    pub format: Format,
    /// Whether the API writes it (`PUT`); the register map still decides whether it may.
    pub writable: bool,
    /// Whether reads show it (a command such as "clear the counter" is written only).
    pub shown: bool,
}

impl Field {
    /// The first address of item `n`'s value.
    pub fn addr(&self, n: u16) -> u16 {
        self.base.wrapping_add(self.stride.wrapping_mul(n))
    }

    /// How many addresses the value takes.
    pub fn words(&self) -> u16 {
        match self.format {
            Format::Long | Format::Ipv4 => 2,
            _ => 1,
        }
    }
}

/// A resource: a list of `count` items (channels) or, with `count` 0, one object.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resource {
    /// Its path segment under `/api/v1/`.
    pub name: &'static str,
    /// Items in the list, 0 for one object.
    pub count: u16,
    /// Its fields.
    pub fields: &'static [Field],
}

impl Resource {
    /// The field called `name`.
    pub fn field(&self, name: &str) -> Option<&'static Field> {
        self.fields.iter().find(|f| f.name == name)
    }
}

const fn field(name: &'static str, table: Table, base: u16, stride: u16, format: Format, writable: bool) -> Field {
    Field { name, table, base, stride, format, writable, shown: true }
}

const fn shown(name: &'static str, base: u16, format: Format) -> Field {
    field(name, Table::Registers, base, 0, format, false)
}

/// The register names of a channel status (registers 40225-40232), by value.
pub const STATUS_NAMES: [&str; ChannelStatus::ALL.len()] =
    ["ok", "open", "over range", "under range", "disabled", "front-end fault", "cold-junction fault"];

/// The names of the 8350's DI modes (spec §3.2), by register value.
pub const DI_MODE_NAMES: [&str; 5] = ["normal", "counter", "latch rising", "latch falling", "frequency"];

/// The names of the 8350's DO modes (spec §3.2), by register value.
pub const DO_MODE_NAMES: [&str; 2] = ["normal", "pulse"];

/// The names of the 8318's open-input values (extensions §2), by register value.
pub const OPEN_VALUE_NAMES: [&str; 2] = ["upscale", "downscale"];

/// The diagnostics and security counters (extensions §1, docs/diagnostics.md); a field the
/// module does not map (the 8350's output timing on the 8318) is left out of its answer.
pub const DIAGNOSTICS: Resource = Resource {
    name: "diagnostics",
    count: 0,
    fields: &[
        shown("status", diag::REG_MODULE_STATUS, Format::Word),
        shown("uptime_s", diag::REG_UPTIME, Format::Long),
        shown("reset_cause", diag::REG_RESET_CAUSE, Format::Word),
        shown("connections", diag::REG_CONNECTIONS, Format::Word),
        shown("requests", diag::REG_REQUESTS, Format::Long),
        shown("exceptions", diag::REG_EXCEPTIONS, Format::Word),
        shown("security", diag::REG_SECURITY, Format::Word),
        shown("auth_failures", diag::REG_AUTH_FAILURES, Format::Word),
        shown("last_failed_source", diag::REG_LAST_FAILED_SOURCE, Format::Ipv4),
        shown("budget_refusals", diag::REG_BUDGET_REFUSALS, Format::Word),
        shown("access_refusals", diag::REG_ACCESS_REFUSALS, Format::Word),
        shown("update_refusals", diag::REG_UPDATE_REFUSALS, Format::Word),
        shown("write_budget_refusals", diag::REG_WRITE_BUDGET_REFUSALS, Format::Word),
        shown("pattern_underruns", diag::REG_PATTERN_UNDERRUNS, Format::Word),
        shown("output_latency_us", diag::REG_OUTPUT_LATENCY, Format::Word),
        shown("output_latency_worst_us", diag::REG_OUTPUT_LATENCY_WORST, Format::Word),
        shown("mqtt_state", diag::REG_MQTT, Format::Word),
        shown("mqtt_sessions", diag::REG_MQTT + 1, Format::Word),
        shown("mqtt_failures", diag::REG_MQTT + 2, Format::Word),
        shown("mqtt_commands_malformed", diag::REG_MQTT + 3, Format::Word),
        shown("mqtt_commands_refused", diag::REG_MQTT + 4, Format::Word),
        shown("mqtt_commands_ignored", diag::REG_MQTT + 5, Format::Word),
        shown("mqtt_tls_no_time", diag::REG_MQTT + 6, Format::Word),
        shown("mqtt_tls_certificate", diag::REG_MQTT + 7, Format::Word),
        shown("mqtt_tls_handshake", diag::REG_MQTT + 8, Format::Word),
        shown("mqtt_plain_credentials", diag::REG_MQTT + 9, Format::Word),
    ],
};

const R: Table = Table::Registers;
const B: Table = Table::Bits;

/// The 8318's resources.
pub const M8318: &[Resource] = &[
    Resource {
        name: "channels",
        count: m8318::CHANNELS as u16,
        fields: &[
            field("value", R, m8318::REG_VALUE, 1, Format::Engineering, false),
            field("raw", R, m8318::REG_VALUE, 1, Format::Word, false),
            field("status", R, m8318::REG_STATUS, 1, Format::Named(&STATUS_NAMES), false),
            field("enabled", R, m8318::REG_ENABLE_MASK, 0, Format::MaskBit, false),
        ],
    },
    Resource {
        name: "inputs",
        count: 0,
        fields: &[
            field("type", R, m8318::REG_INPUT_TYPE, 0, Format::InputType, true),
            field("enable_mask", R, m8318::REG_ENABLE_MASK, 0, Format::Word, true),
            field("cjc", R, m8318::REG_CJC, 0, Format::Hundredths, false),
            field("cjc_offset", R, m8318::REG_CJC_OFFSET, 0, Format::Hundredths, true),
            field("open_value", R, m8318::REG_OPEN_VALUE, 0, Format::Named(&OPEN_VALUE_NAMES), true),
        ],
    },
    DIAGNOSTICS,
];

/// The 8350's resources.
pub const M8350: &[Resource] = &[
    Resource {
        name: "di",
        count: m8350::DI_CHANNELS as u16,
        fields: &[
            field("state", B, m8350::BIT_DI, 1, Format::Bool, false),
            field("mode", R, m8350::REG_DI_MODE, 1, Format::Named(&DI_MODE_NAMES), true),
            field("counter", R, m8350::REG_COUNTER, 2, Format::Long, false),
            field("frequency", R, m8350::REG_COUNTER, 2, Format::Frequency, false),
            field("counting", B, m8350::BIT_COUNTER, 4, Format::Bool, true),
            Field { shown: false, ..field("clear", B, m8350::BIT_COUNTER + 1, 4, Format::Bool, true) },
            field("overflow", B, m8350::BIT_COUNTER + 2, 4, Format::Bool, true),
            field("latch", B, m8350::BIT_COUNTER + 3, 4, Format::Bool, true),
        ],
    },
    Resource {
        name: "do",
        count: m8350::DO_CHANNELS as u16,
        fields: &[
            field("state", B, m8350::BIT_DO, 1, Format::Bool, true),
            field("mode", R, m8350::REG_DO_MODE, 1, Format::Named(&DO_MODE_NAMES), true),
            field("low_width", R, m8350::REG_PULSE, 2, Format::Long, true),
            field("high_width", R, m8350::REG_PULSE + 12, 2, Format::Long, true),
            field("pulses", R, m8350::REG_PULSE + 24, 2, Format::Long, true),
            field("extra_pulses", R, m8350::REG_PULSE + 36, 2, Format::Long, true),
        ],
    },
    Resource {
        name: "watchdog",
        count: 0,
        fields: &[
            field("timeout", R, m8350::REG_WD_TIMEOUT, 0, Format::Word, true),
            field("mode", R, m8350::REG_WD_MODE, 0, Format::Word, true),
            field("tripped", R, m8350::REG_WD_STATUS, 0, Format::Word, true),
            field("safe_values", R, m8350::REG_SAFE_VALUES, 0, Format::Word, true),
            field("power_on_values", R, m8350::REG_POWER_ON, 0, Format::Word, true),
        ],
    },
    DIAGNOSTICS,
];

/// The resources of the module named `model` (8318h or 8350h; none for another).
pub fn of(model: u16) -> &'static [Resource] {
    match model {
        m8318::MODULE_NAME => M8318,
        m8350::MODULE_NAME => M8350,
        _ => &[],
    }
}

/// The engineering unit of an input type.
pub fn unit(t: &m8318::InputType) -> &'static str {
    match t.kind {
        m8318::Kind::Voltage => "mV",
        m8318::Kind::Current => "mA",
        m8318::Kind::Thermocouple(_) => "°C",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Access;

    /// Every address a field names is mapped in its module's table for the access the field
    /// claims (the register maps' own access rules, spec §2.1, §3.1, §3.2).
    #[test]
    fn every_field_names_mapped_addresses() {
        for (resources, access) in
            [(M8318, m8318::access as fn(Table, u16) -> Access), (M8350, m8350::access as fn(Table, u16) -> Access)]
        {
            for r in resources {
                for f in r.fields {
                    let optional = f.base >= diag::REG_PATTERN_UNDERRUNS && r.name == "diagnostics";
                    for n in 0..r.count.max(1) {
                        for a in f.addr(n)..f.addr(n) + f.words() {
                            let got = access(f.table, a);
                            if optional && got == Access::None {
                                continue;
                            }
                            assert!(got.readable() || !f.shown, "{}.{} item {n}: {a:04X} {got:?}", r.name, f.name);
                            assert!(!f.writable || got.writable(), "{}.{} item {n}: {a:04X} {got:?}", r.name, f.name);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_names_follow_the_register_values() {
        for status in ChannelStatus::ALL {
            assert_eq!(STATUS_NAMES[status as usize], status.name());
        }
        assert_eq!(DI_MODE_NAMES[m8350::DiMode::Frequency as usize], "frequency");
        assert_eq!(DO_MODE_NAMES[m8350::DoMode::Pulse as usize], "pulse");
        // Spec §3.2: the pulse fields of DO n at 18h+2n, 24h+2n, 30h+2n, 3Ch+2n.
        let fields = M8350[1].fields;
        assert_eq!(
            [fields[2].addr(5), fields[3].addr(0), fields[4].addr(0), fields[5].addr(5)],
            [0x22, 0x24, 0x30, 0x46]
        );

        // Every field a write or a read names is at the address the spec gives it, found by its
        // name (a swap of two fields' addresses, or a field moved, fails): the literals are the
        // spec's (modules.md §2.1, §3.1, §3.2; extensions.md §2, §3), item by item.
        let at = |resources: &[Resource], resource: &str, field: &str, n: u16| {
            let r = resources.iter().find(|r| r.name == resource).unwrap_or_else(|| panic!("{resource}"));
            let f = r.field(field).unwrap_or_else(|| panic!("{resource}.{field}"));
            (f.table, f.addr(n))
        };
        let (reg, bit) = (Table::Registers, Table::Bits);
        // RemoDAQ-8350, extensions §3: 0130h timeout, 0131h safe output values, 0132h mode,
        // 0133h status, 0134h power-on output values.
        for (field, addr) in [
            ("timeout", 0x130),
            ("safe_values", 0x131),
            ("mode", 0x132),
            ("tripped", 0x133),
            ("power_on_values", 0x134),
        ] {
            assert_eq!(at(M8350, "watchdog", field, 0), (reg, addr), "watchdog.{field}");
        }
        // §3.1 bits: DI n state at n, DO n at 10h + n, DI n's counter run, clear, overflow and
        // latch at 20h + 4n, 21h + 4n, 22h + 4n, 23h + 4n; §3.2 registers: DI n counter at 2n,
        // DI n mode at 100h + n, DO n mode at 110h + n.
        for n in [0u16, 1, 11] {
            assert_eq!(at(M8350, "di", "state", n), (bit, n));
            assert_eq!(at(M8350, "di", "counter", n), (reg, 2 * n));
            assert_eq!(at(M8350, "di", "frequency", n), (reg, 2 * n));
            assert_eq!(at(M8350, "di", "mode", n), (reg, 0x100 + n));
            for (field, offset) in [("counting", 0x20), ("clear", 0x21), ("overflow", 0x22), ("latch", 0x23)] {
                assert_eq!(at(M8350, "di", field, n), (bit, offset + 4 * n), "di.{field} {n}");
            }
        }
        for n in [0u16, 1, 5] {
            assert_eq!(at(M8350, "do", "state", n), (bit, 0x10 + n));
            assert_eq!(at(M8350, "do", "mode", n), (reg, 0x110 + n));
            for (field, base) in [("low_width", 0x18), ("high_width", 0x24), ("pulses", 0x30), ("extra_pulses", 0x3C)] {
                assert_eq!(at(M8350, "do", field, n), (reg, base + 2 * n), "do.{field} {n}");
            }
        }
        // RemoDAQ-8318, §2.1: channel n value at n, input type 00C8h, CJC 0008h, CJC offset
        // 00D7h, enable mask 00DCh (bit n = channel n); extensions §2: channel n status at
        // 00E0h + n, the open-input value 00E8h.
        for (field, addr) in
            [("type", 0xC8), ("enable_mask", 0xDC), ("cjc", 0x08), ("cjc_offset", 0xD7), ("open_value", 0xE8)]
        {
            assert_eq!(at(M8318, "inputs", field, 0), (reg, addr), "inputs.{field}");
        }
        for n in [0u16, 3, 7] {
            assert_eq!(at(M8318, "channels", "value", n), (reg, n));
            assert_eq!(at(M8318, "channels", "raw", n), (reg, n));
            assert_eq!(at(M8318, "channels", "status", n), (reg, 0xE0 + n));
            // One register for every channel, bit n of it.
            assert_eq!(at(M8318, "channels", "enabled", n), (reg, 0xDC), "channels.enabled {n}");
        }
        let enabled = M8318[0].field("enabled").map(|f| f.format);
        assert_eq!(enabled, Some(Format::MaskBit));
        // Extensions §2: 0 upscale (factory), 1 downscale.
        assert_eq!(OPEN_VALUE_NAMES, ["upscale", "downscale"]);
    }
}
