//! The topics (docs/mqtt.md): every point under one prefix, `remodaq/<model>/<mac>` unless the
//! user sets another, and the 8350's command topics `<prefix>/do/<n>/set`.

use core::fmt::Write as _;

pub use remodaq_shared::mqtt::{prefix_is_valid, MAX_PREFIX};

/// The longest topic: the prefix and the longest suffix (`/do/5/set`, `/status`).
pub const MAX_TOPIC: usize = MAX_PREFIX + 16;

/// A topic.
pub type Topic = heapless::String<MAX_TOPIC>;

/// The kinds of point, as their topics name them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// An 8318 analog input (`ai`).
    Ai,
    /// An 8350 digital input (`di`).
    Di,
    /// An 8350 digital output (`do`).
    Do,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Ai => "ai",
            Kind::Di => "di",
            Kind::Do => "do",
        }
    }
}

/// The default prefix: `remodaq/<model>/<mac>`, the model as the module names itself (`8318`)
/// and the MAC in 12 lower-case hex digits.
pub fn default_prefix(model: u16, mac: [u8; 6]) -> heapless::String<MAX_PREFIX> {
    let mut p = heapless::String::new();
    let mut digits = [0u8; 12];
    let mac = remodaq_protocol::web::hex(&mac, &mut digits).unwrap_or("");
    let _ = write!(p, "remodaq/{model:04X}/{mac}");
    p
}

/// `<prefix>/<kind>/<n>`: a point's topic.
pub fn point(prefix: &str, kind: Kind, n: u8) -> Topic {
    let mut t = Topic::new();
    let _ = write!(t, "{prefix}/{}/{n}", kind.name());
    t
}

/// `<prefix>/<leaf>` (`status`, `cjc`).
pub fn leaf(prefix: &str, leaf: &str) -> Topic {
    let mut t = Topic::new();
    let _ = write!(t, "{prefix}/{leaf}");
    t
}

/// The filter the 8350 subscribes to for its commands: `<prefix>/do/+/set`.
pub fn command_filter(prefix: &str) -> Topic {
    leaf(prefix, "do/+/set")
}

/// The output a command topic names: `<prefix>/do/<n>/set` with `n` below `outputs` (decimal,
/// no sign or leading zero); `None` for any other topic.
pub fn command_output(prefix: &str, topic: &str, outputs: u8) -> Option<u8> {
    let n = topic.strip_prefix(prefix)?.strip_prefix("/do/")?.strip_suffix("/set")?;
    let canonical = !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) && (n == "0" || !n.starts_with('0'));
    let n: u8 = n.parse().ok().filter(|_| canonical)?;
    (n < outputs).then_some(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefixes() {
        for ok in ["remodaq/8350/0080e1000001", "plant-3/line 2", "a"] {
            assert!(prefix_is_valid(ok), "{ok}");
        }
        let long = "x".repeat(MAX_PREFIX + 1);
        for bad in ["", "a/+/b", "a/#", "$SYS/x", "/a", "a/", "a//b", "a\nb", "é", long.as_str()] {
            assert!(!prefix_is_valid(bad), "{bad:?}");
        }
        assert!(prefix_is_valid(&"x".repeat(MAX_PREFIX)));
    }

    #[test]
    fn the_default_prefix_names_the_model_and_the_mac() {
        assert_eq!(default_prefix(0x8350, [0x00, 0x80, 0xE1, 0x01, 0xAB, 0xCD]).as_str(), "remodaq/8350/0080e101abcd");
        assert!(prefix_is_valid(&default_prefix(0x8318, [0xFF; 6])));
    }

    #[test]
    fn topics_of_points() {
        let p = default_prefix(0x8318, [0, 1, 2, 3, 4, 5]);
        assert_eq!(point(&p, Kind::Ai, 7).as_str(), "remodaq/8318/000102030405/ai/7");
        assert_eq!(leaf(&p, "status").as_str(), "remodaq/8318/000102030405/status");
        assert_eq!(command_filter("x").as_str(), "x/do/+/set");
        // The longest prefix with the longest suffix fits.
        let longest = "x".repeat(MAX_PREFIX);
        assert!(command_filter(&longest).len() <= MAX_TOPIC && point(&longest, Kind::Do, 5).ends_with("/do/5"));
    }

    #[test]
    fn command_topics() {
        assert_eq!(command_output("p/q", "p/q/do/0/set", 6), Some(0));
        assert_eq!(command_output("p/q", "p/q/do/5/set", 6), Some(5));
        for other in [
            "p/q/do/6/set",
            "p/q/do/05/set",
            "p/q/do/-1/set",
            "p/q/do//set",
            "p/q/do/0",
            "p/q/di/0/set",
            "p/qq/do/0/set",
            "x/do/0/set",
            "p/q/do/0/set/x",
            "p/q/do/+/set",
            "p/q/do/256/set",
        ] {
            assert_eq!(command_output("p/q", other, 6), None, "{other}");
        }
    }
}
