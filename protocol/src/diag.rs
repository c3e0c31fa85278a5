//! Diagnostics registers of both modules (extensions §1), read-only.

use crate::Word;

/// 40241: module status (bits below).
pub const REG_MODULE_STATUS: u16 = 0x00F0;
/// 40242-40243: seconds since start, 32 bits, low word first.
pub const REG_UPTIME: u16 = 0x00F1;
/// 40244: reset cause ([`reset_cause`]).
pub const REG_RESET_CAUSE: u16 = 0x00F3;
/// 40245: Modbus/TCP clients connected now.
pub const REG_CONNECTIONS: u16 = 0x00F4;
/// 40246-40247: Modbus requests answered since start, 32 bits, low word first.
pub const REG_REQUESTS: u16 = 0x00F5;
/// 40248: exception responses sent since start, 16 bits, wrapping.
pub const REG_EXCEPTIONS: u16 = 0x00F7;

/// 40249: security flags ([`security`]).
pub const REG_SECURITY: u16 = 0x00F8;
/// 40250: failed authentications (wrong proofs) since start, 16 bits, wrapping.
pub const REG_AUTH_FAILURES: u16 = 0x00F9;
/// 40251-40252: the source address of the last failed authentication (a.b, then c.d).
pub const REG_LAST_FAILED_SOURCE: u16 = 0x00FA;
/// 40253: proofs not checked because the guessing budget was spent, 16 bits, wrapping.
pub const REG_BUDGET_REFUSALS: u16 = 0x00FC;
/// 40254: Modbus writes refused by the allow-list, 16 bits, wrapping.
pub const REG_ACCESS_REFUSALS: u16 = 0x00FD;
/// 40255: firmware updates refused (authentication, signature, model, password), 16 bits.
pub const REG_UPDATE_REFUSALS: u16 = 0x00FE;
/// 40256: settings writes refused because the commit budget was spent (flash wear), 16 bits.
pub const REG_WRITE_BUDGET_REFUSALS: u16 = 0x00FF;
/// 40321-40324: the first 8 bytes of the SHA-256 of the firmware update key, high byte first.
pub const REG_UPDATE_KEY: u16 = 0x0140;
/// 40325: times the 8350's output pattern ran dry before it was refilled (the outputs replayed
/// old ticks) since start, 16 bits, wrapping; 0 on the 8318.
pub const REG_PATTERN_UNDERRUNS: u16 = 0x0144;
/// 40326: µs from the 8350's last output command (a DO bit, a hold, a mode) to the first tick
/// of the output pattern that plays it, as the module measured it; 65535 or more reads 65535;
/// 0 before any command, and on the 8318.
pub const REG_OUTPUT_LATENCY: u16 = 0x0145;
/// 40327: the longest such latency since start, µs (65535 or more reads 65535).
pub const REG_OUTPUT_LATENCY_WORST: u16 = 0x0146;
/// 40328-40337: MQTT (docs/mqtt.md): its state ([`mqtt`]), then counters since start, 16 bits,
/// wrapping: sessions established, connections that failed or broke, commands refused as
/// malformed or oversized, commands refused by the module's checks, commands ignored (commands
/// off, or the topic names no output), TLS not tried for want of a time, the broker's
/// certificate refused, TLS handshakes failed otherwise, credentials refused with TLS off.
pub const REG_MQTT: u16 = 0x0147;

/// MQTT's registers, from [`REG_MQTT`]: which is which, and the state's values.
pub mod mqtt {
    /// The state (40328).
    pub const STATE: u8 = 0;
    /// Sessions established (40329).
    pub const SESSIONS: u8 = 1;
    /// Connections that failed (the broker not reached, the session refused) or broke (40330).
    pub const FAILURES: u8 = 2;
    /// Commands refused: malformed or oversized (40331).
    pub const MALFORMED: u8 = 3;
    /// Commands refused by the module's checks: the register map's, the tripped host watchdog
    /// (40332).
    pub const REFUSED: u8 = 4;
    /// Commands ignored: commands off, or the topic names no output (40333).
    pub const IGNORED: u8 = 5;
    /// TLS connections not tried: the module has no time yet (40334).
    pub const NO_TIME: u8 = 6;
    /// TLS connections refused: the broker's certificate (another CA, another host name, not
    /// valid now) (40335).
    pub const CERTIFICATE: u8 = 7;
    /// TLS handshakes that failed otherwise (40336).
    pub const HANDSHAKE: u8 = 8;
    /// Settings refused: credentials set with TLS off (they would cross in clear), or stored for
    /// another broker (its address, port, name or CA changed since) (40337).
    pub const PLAIN_CREDENTIALS: u8 = 9;
    /// How many registers.
    pub const REGISTERS: u16 = 10;

    /// State: off (no socket for it).
    pub const OFF: u16 = 0;
    /// State: connecting, or waiting to try again.
    pub const CONNECTING: u16 = 1;
    /// State: connected, publishing.
    pub const CONNECTED: u16 = 2;
    /// State: on, but its settings cannot be used (TLS without a CA certificate stored, or in an
    /// image without TLS; credentials with TLS off): not connecting.
    pub const UNUSABLE: u16 = 3;
}

/// Security flag bits (register 40249).
pub mod security {
    /// The factory password is in force (firmware updates and allow-list changes refused).
    pub const FACTORY_PASSWORD: u16 = 1 << 0;
}

/// Module status bits.
pub mod status {
    /// 8318: the ADC does not answer or a conversion timed out; 8350: input samples were lost
    /// since the last read of the module status.
    pub const FRONT_END_FAULT: u16 = 1 << 0;
    /// 8318: the cold-junction sensor cannot be read.
    pub const CJC_FAULT: u16 = 1 << 1;
    /// The last settings commit failed.
    pub const STORE_FAULT: u16 = 1 << 2;
    /// This run started after a watchdog reset.
    pub const WATCHDOG_RESET: u16 = 1 << 3;
    /// 8350: the host watchdog tripped (extensions §3).
    pub const HOST_WATCHDOG: u16 = 1 << 4;
    /// The inputs are not valid yet (the first acquisition is pending).
    pub const INPUTS_PENDING: u16 = 1 << 5;
    /// Every bit with a meaning, and its name.
    pub const NAMES: [(u16, &str); 6] = [
        (FRONT_END_FAULT, "front-end fault"),
        (CJC_FAULT, "cold-junction fault"),
        (STORE_FAULT, "settings store fault"),
        (WATCHDOG_RESET, "started after a watchdog reset"),
        (HOST_WATCHDOG, "host watchdog tripped"),
        (INPUTS_PENDING, "inputs not valid yet"),
    ];
}

/// Reset cause values (register 40244).
pub mod reset_cause {
    /// Power-on.
    pub const POWER_ON: u16 = 0;
    /// Watchdog.
    pub const WATCHDOG: u16 = 1;
    /// Software restart (restart command, firmware update).
    pub const SOFTWARE: u16 = 2;
    /// Reset pin.
    pub const PIN: u16 = 3;
    /// Brown-out.
    pub const BROWN_OUT: u16 = 4;
    /// The board cannot tell.
    pub const UNKNOWN: u16 = 0xFFFF;

    /// The name of a reset cause value.
    pub fn name(value: u16) -> &'static str {
        match value {
            POWER_ON => "power-on",
            WATCHDOG => "watchdog",
            SOFTWARE => "software restart",
            PIN => "reset pin",
            BROWN_OUT => "brown-out",
            _ => "unknown",
        }
    }
}

/// One diagnostics register.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Diag {
    /// Module status.
    Status,
    /// A word of the uptime.
    Uptime(Word),
    /// Reset cause.
    ResetCause,
    /// Clients connected.
    Connections,
    /// A word of the requests answered.
    Requests(Word),
    /// Exceptions sent.
    Exceptions,
    /// Security flags.
    Security,
    /// Failed authentications.
    AuthFailures,
    /// A word of the last failed source address.
    LastFailedSource(Word),
    /// Proofs refused by the budget.
    BudgetRefusals,
    /// Writes refused by the allow-list.
    AccessRefusals,
    /// Updates refused.
    UpdateRefusals,
    /// Writes refused by the commit budget.
    WriteBudgetRefusals,
    /// Word 0-3 of the update key's fingerprint.
    UpdateKey(u8),
    /// Output pattern underruns.
    PatternUnderruns,
    /// The last output command's latency, µs.
    OutputLatency,
    /// The longest output command latency, µs.
    OutputLatencyWorst,
    /// MQTT's register `n` ([`mqtt`]).
    Mqtt(u8),
}

/// The diagnostics register at `addr` (4X table), if it is one.
pub fn decode(addr: u16) -> Option<Diag> {
    Some(match addr {
        REG_MODULE_STATUS => Diag::Status,
        a if (REG_UPTIME..REG_UPTIME + 2).contains(&a) => Diag::Uptime(Word::of(a - REG_UPTIME)),
        REG_RESET_CAUSE => Diag::ResetCause,
        REG_CONNECTIONS => Diag::Connections,
        a if (REG_REQUESTS..REG_REQUESTS + 2).contains(&a) => Diag::Requests(Word::of(a - REG_REQUESTS)),
        REG_EXCEPTIONS => Diag::Exceptions,
        REG_SECURITY => Diag::Security,
        REG_AUTH_FAILURES => Diag::AuthFailures,
        a if (REG_LAST_FAILED_SOURCE..REG_LAST_FAILED_SOURCE + 2).contains(&a) => {
            Diag::LastFailedSource(Word::of(a - REG_LAST_FAILED_SOURCE))
        }
        REG_BUDGET_REFUSALS => Diag::BudgetRefusals,
        REG_ACCESS_REFUSALS => Diag::AccessRefusals,
        REG_UPDATE_REFUSALS => Diag::UpdateRefusals,
        REG_WRITE_BUDGET_REFUSALS => Diag::WriteBudgetRefusals,
        a if (REG_UPDATE_KEY..REG_UPDATE_KEY + 4).contains(&a) => Diag::UpdateKey((a - REG_UPDATE_KEY) as u8),
        REG_PATTERN_UNDERRUNS => Diag::PatternUnderruns,
        REG_OUTPUT_LATENCY => Diag::OutputLatency,
        REG_OUTPUT_LATENCY_WORST => Diag::OutputLatencyWorst,
        a if (REG_MQTT..REG_MQTT + mqtt::REGISTERS).contains(&a) => Diag::Mqtt((a - REG_MQTT) as u8),
        _ => return None,
    })
}

impl Diag {
    /// The register's PDU address.
    pub fn addr(self) -> u16 {
        match self {
            Diag::Status => REG_MODULE_STATUS,
            Diag::Uptime(w) => REG_UPTIME + w.offset(),
            Diag::ResetCause => REG_RESET_CAUSE,
            Diag::Connections => REG_CONNECTIONS,
            Diag::Requests(w) => REG_REQUESTS + w.offset(),
            Diag::Exceptions => REG_EXCEPTIONS,
            Diag::Security => REG_SECURITY,
            Diag::AuthFailures => REG_AUTH_FAILURES,
            Diag::LastFailedSource(w) => REG_LAST_FAILED_SOURCE + w.offset(),
            Diag::BudgetRefusals => REG_BUDGET_REFUSALS,
            Diag::AccessRefusals => REG_ACCESS_REFUSALS,
            Diag::UpdateRefusals => REG_UPDATE_REFUSALS,
            Diag::WriteBudgetRefusals => REG_WRITE_BUDGET_REFUSALS,
            Diag::UpdateKey(i) => REG_UPDATE_KEY + u16::from(i),
            Diag::PatternUnderruns => REG_PATTERN_UNDERRUNS,
            Diag::OutputLatency => REG_OUTPUT_LATENCY,
            Diag::OutputLatencyWorst => REG_OUTPUT_LATENCY_WORST,
            Diag::Mqtt(n) => REG_MQTT + u16::from(n),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_registers_of_extensions_1_and_the_security_events() {
        let mapped: std::vec::Vec<u16> = (0..=u16::MAX).filter(|a| decode(*a).is_some()).collect();
        // 40241-40248 (extensions §1), 40249-40256 and 40321-40337 (docs/diagnostics.md).
        let expected = (40241..=40256).chain(40321..=40337).map(|r| r - 40001);
        assert_eq!(mapped, expected.collect::<std::vec::Vec<_>>());
        for a in mapped {
            assert_eq!(decode(a).map(Diag::addr), Some(a));
        }
    }
}
