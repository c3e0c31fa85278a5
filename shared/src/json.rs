//! Bodies that are one flat JSON object: the web console API's requests (`{"value": 5}`,
//! `{"ip": "10.0.0.5", ...}`, `{"networks": ["10.0.0.0/8"]}`) and MQTT's commands
//! (`{"level": true}`), read without serde (docs/web.md, "Budgets": serde-json-core's
//! deserializers, one per body type, took about 9 KB of flash).
//!
//! What is taken, RFC 8259 narrowed to what the API's bodies hold:
//! - one object, whitespace around its tokens;
//! - members whose values are strings, numbers, `true`, `false`, `null`, or arrays of strings
//!   or of numbers (all of one kind);
//!   nested objects and arrays of anything else are refused;
//! - strings without escapes or control characters (no field of the API needs one);
//! - at most [`MAX_MEMBERS`] members, each name once (a duplicate is refused: which would
//!   count is not said by RFC 8259).
//!
//! Members the API does not know are ignored when their values are of the kinds above (serde
//! ignored any value; no client of the API sends other members).

/// Most members a body may have.
pub const MAX_MEMBERS: usize = 13;

/// A member's value, as its JSON text says it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Value<'a> {
    /// A string, without its quotes.
    Str(&'a str),
    /// A number, as written (`-1.5e3`): [`Object::u16`] and [`Object::u32`] take integers only.
    Number(&'a str),
    /// `true` or `false`.
    Bool(bool),
    /// `null`.
    Null,
    /// An array of strings: its text between the brackets (see [`Object::strings`]).
    Strings(&'a str),
    /// An array of numbers: its text between the brackets (see [`Object::numbers`]).
    Numbers(&'a str),
}

/// A request body that is one flat JSON object.
#[derive(Clone, Copy, Debug)]
pub struct Object<'a> {
    /// The body (valid UTF-8, checked as a whole).
    text: &'a str,
}

/// A reader over a body's bytes.
struct Cursor<'a> {
    text: &'a str,
    at: usize,
}

impl<'a> Cursor<'a> {
    fn peek(&self) -> Option<u8> {
        self.text.as_bytes().get(self.at).copied()
    }

    fn space(&mut self) {
        while matches!(self.peek(), Some(b' ' | b'\t' | b'\r' | b'\n')) {
            self.at += 1;
        }
    }

    /// Takes `b` after any whitespace.
    fn eat(&mut self, b: u8) -> bool {
        self.space();
        let here = self.peek() == Some(b);
        if here {
            self.at += 1;
        }
        here
    }

    /// Takes `word` where the cursor stands.
    fn word(&mut self, word: &str) -> bool {
        let here = self.text.get(self.at..).is_some_and(|rest| rest.starts_with(word));
        if here {
            self.at += word.len();
        }
        here
    }

    /// Takes the ASCII digits where the cursor stands; how many.
    fn digits(&mut self) -> usize {
        let start = self.at;
        while self.peek().is_some_and(|b| b.is_ascii_digit()) {
            self.at += 1;
        }
        self.at - start
    }

    /// A string (after whitespace): its text between the quotes.
    fn string(&mut self) -> Option<&'a str> {
        if !self.eat(b'"') {
            return None;
        }
        let start = self.at;
        loop {
            match self.peek()? {
                b'"' => break,
                b'\\' | 0..=0x1f => return None,
                _ => self.at += 1,
            }
        }
        let s = self.text.get(start..self.at)?;
        self.at += 1;
        Some(s)
    }

    /// A number (RFC 8259, section 6) where the cursor stands.
    fn number(&mut self) -> Option<&'a str> {
        let start = self.at;
        self.word("-");
        match self.peek() {
            Some(b'0') => self.at += 1,
            Some(b'1'..=b'9') => {
                self.digits();
            }
            _ => return None,
        }
        if self.word(".") && self.digits() == 0 {
            return None;
        }
        if matches!(self.peek(), Some(b'e' | b'E')) {
            self.at += 1;
            let _ = self.word("+") || self.word("-");
            if self.digits() == 0 {
                return None;
            }
        }
        self.text.get(start..self.at)
    }

    /// A member's value (after whitespace).
    fn value(&mut self) -> Option<Value<'a>> {
        self.space();
        match self.peek()? {
            b'"' => self.string().map(Value::Str),
            b'[' => {
                self.at += 1;
                let start = self.at;
                // An array of strings, or of numbers when its first item is one.
                self.space();
                let numbers = self.peek().is_some_and(|b| b == b'-' || b.is_ascii_digit());
                if !self.eat(b']') {
                    loop {
                        if numbers {
                            self.space();
                            self.number()?;
                        } else {
                            self.string()?;
                        }
                        if self.eat(b']') {
                            break;
                        }
                        if !self.eat(b',') {
                            return None;
                        }
                    }
                }
                let inner = self.text.get(start..self.at - 1)?;
                Some(if numbers { Value::Numbers(inner) } else { Value::Strings(inner) })
            }
            _ if self.word("true") => Some(Value::Bool(true)),
            _ if self.word("false") => Some(Value::Bool(false)),
            _ if self.word("null") => Some(Value::Null),
            _ => self.number().map(Value::Number),
        }
    }

    /// The next member (`"name": value`, after the `{` or a `,`).
    fn member(&mut self) -> Option<(&'a str, Value<'a>)> {
        let name = self.string()?;
        if !self.eat(b':') {
            return None;
        }
        Some((name, self.value()?))
    }
}

/// A JSON number that is a plain integer from 0 to 2^32 - 1 (no sign, fraction or exponent).
fn plain_u32(number: &str) -> Option<u32> {
    number.bytes().all(|b| b.is_ascii_digit()).then(|| number.parse().ok()).flatten()
}

impl<'a> Object<'a> {
    /// `body` when it is one flat JSON object as the module reads them (above).
    pub fn parse(body: &'a [u8]) -> Option<Self> {
        let text = core::str::from_utf8(body).ok()?;
        let mut c = Cursor { text, at: 0 };
        if !c.eat(b'{') {
            return None;
        }
        let mut names: heapless::Vec<&str, MAX_MEMBERS> = heapless::Vec::new();
        if !c.eat(b'}') {
            loop {
                let (name, _) = c.member()?;
                if names.contains(&name) {
                    return None;
                }
                names.push(name).ok()?;
                if c.eat(b'}') {
                    break;
                }
                if !c.eat(b',') {
                    return None;
                }
            }
        }
        c.space();
        (c.at == text.len()).then_some(Object { text })
    }

    /// The value of member `name`, if the object has one.
    pub fn get(&self, name: &str) -> Option<Value<'a>> {
        let mut c = Cursor { text: self.text, at: 0 };
        c.eat(b'{');
        loop {
            let (n, v) = c.member()?;
            if n == name {
                return Some(v);
            }
            c.eat(b',');
        }
    }

    /// Member `name` as a string.
    pub fn str(&self, name: &str) -> Option<&'a str> {
        match self.get(name)? {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }

    /// Member `name` as a number, as written.
    pub fn number(&self, name: &str) -> Option<&'a str> {
        match self.get(name)? {
            Value::Number(n) => Some(n),
            _ => None,
        }
    }

    /// Member `name` as `true` or `false`.
    pub fn bool(&self, name: &str) -> Option<bool> {
        match self.get(name)? {
            Value::Bool(b) => Some(b),
            _ => None,
        }
    }

    /// Member `name` as an integer from 0 to 65535 (no sign, fraction or exponent).
    pub fn u16(&self, name: &str) -> Option<u16> {
        self.u32(name).and_then(|v| u16::try_from(v).ok())
    }

    /// Member `name` as an integer from 0 to 2^32 - 1 (no sign, fraction or exponent).
    pub fn u32(&self, name: &str) -> Option<u32> {
        plain_u32(self.number(name)?)
    }

    /// Member `name` as an array of integers from 0 to 2^32 - 1: each in turn (`None` for an
    /// item that is not one).
    pub fn u32s(&self, name: &str) -> Option<impl Iterator<Item = Option<u32>> + 'a> {
        let Value::Numbers(inner) = self.get(name)? else { return None };
        let mut c = Cursor { text: inner, at: 0 };
        Some(core::iter::from_fn(move || {
            c.eat(b',');
            c.space();
            Some(plain_u32(c.number()?))
        }))
    }

    /// Member `name` as an array of strings: each in turn.
    pub fn strings(&self, name: &str) -> Option<impl Iterator<Item = &'a str>> {
        let Value::Strings(inner) = self.get(name)? else { return None };
        let mut c = Cursor { text: inner, at: 0 };
        Some(core::iter::from_fn(move || {
            c.eat(b',');
            c.string()
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bodies the API documents (docs/openapi.yaml) and the console sends, read back.
    #[test]
    fn the_bodies_of_the_api_are_read() {
        let o = Object::parse(br#"{"value": 65535}"#).expect("an object");
        assert_eq!(o.u16("value"), Some(65535));
        assert_eq!(o.u32("value"), Some(65535));
        let o = Object::parse(br#" { "value" : true } "#).expect("an object");
        assert_eq!(o.bool("value"), Some(true));
        assert_eq!(o.u16("value"), None);
        let o = Object::parse(br#"{"value":"Type J"}"#).expect("an object");
        assert_eq!(o.str("value"), Some("Type J"));
        let o = Object::parse("{\"unit\":\"°C\",\"名\":\"温度\",\"value\":\"±2.5 V\"}".as_bytes()).expect("an object");
        assert_eq!((o.str("unit"), o.str("名"), o.str("value")), (Some("°C"), Some("温度"), Some("±2.5 V")));
        let o = Object::parse(
            br#"{"ip":"10.0.5.20","mask":"255.255.0.0","gateway":"10.0.0.1","modbus_port":502,"http_port":8080}"#,
        )
        .expect("an object");
        assert_eq!(
            (o.str("ip"), o.str("gateway"), o.u16("http_port")),
            (Some("10.0.5.20"), Some("10.0.0.1"), Some(8080))
        );
        let o = Object::parse(br#"{"networks": ["10.0.0.0/8", "192.168.1.7/32"]}"#).expect("an object");
        let nets: std::vec::Vec<&str> = o.strings("networks").expect("strings").collect();
        assert_eq!(nets, ["10.0.0.0/8", "192.168.1.7/32"]);
        let o = Object::parse(br#"{"networks":[]}"#).expect("an object");
        assert_eq!(o.strings("networks").expect("strings").count(), 0);
        assert_eq!(Object::parse(b"{}").expect("an object").get("value"), None);
        // MQTT's deadbands: an array of numbers.
        let o = Object::parse(br#"{"deadbands": [0, 50, 4294967295, 1.5, 7]}"#).expect("an object");
        let bands: std::vec::Vec<Option<u32>> = o.u32s("deadbands").expect("numbers").collect();
        assert_eq!(bands, [Some(0), Some(50), Some(u32::MAX), None, Some(7)]);
        assert!(o.strings("deadbands").is_none() && o.u32s("networks").is_none());
    }

    /// Numbers as RFC 8259 writes them; the integer fields take plain integers only.
    #[test]
    fn numbers() {
        for (text, want) in [
            ("0", Some(0)),
            ("4294967295", Some(u32::MAX)),
            ("4294967296", None),
            ("-1", None),
            ("1.0", None),
            ("1e2", None),
        ] {
            let body = std::format!(r#"{{"value":{text}}}"#);
            let o = Object::parse(body.as_bytes()).unwrap_or_else(|| panic!("{text} is JSON"));
            assert_eq!(o.get("value"), Some(Value::Number(text)));
            assert_eq!(o.u32("value"), want, "{text}");
        }
        for text in ["01", "+1", "1.", ".5", "1e", "-", "0x10", "1e+", "Infinity", "NaN"] {
            let body = std::format!(r#"{{"value":{text}}}"#);
            assert!(Object::parse(body.as_bytes()).is_none(), "{text} is no JSON number");
        }
        assert_eq!(Object::parse(br#"{"value":65536}"#).and_then(|o| o.u16("value")), None);
    }

    /// What is not one flat object of the API's kinds of value is refused whole.
    #[test]
    fn other_json_and_not_json_are_refused() {
        for body in [
            &b""[..],
            b"null",
            b"[1]",
            b"{",
            b"{}}",
            b"{} x",
            br#"{"value":1,}"#,
            br#"{"value" 1}"#,
            br#"{value:1}"#,
            br#"{"value":1 "b":2}"#,
            br#"{"value":{"a":1}}"#,
            br#"{"networks":[1,"a"]}"#,
            br#"{"networks":["a",1]}"#,
            br#"{"deadbands":[1,]}"#,
            br#"{"deadbands":[01]}"#,
            br#"{"networks":["a",]}"#,
            br#"{"networks":[["a"]]}"#,
            br#"{"value":"a\"b"}"#,
            b"{\"value\":\"a\nb\"}",
            br#"{"value":tru}"#,
            br#"{"value":1,"value":2}"#,
            br#"{"a":1,"b":2,"c":3,"d":4,"e":5,"f":6,"g":7,"h":8,"i":9,"j":10,"k":11,"l":12,"m":13,"n":14}"#,
            b"{\"value\":\"\xff\"}",
        ] {
            assert!(Object::parse(body).is_none(), "{:?}", std::string::String::from_utf8_lossy(body));
        }
    }

    /// A member the API does not know is ignored; a value of the wrong kind reads as none.
    #[test]
    fn unknown_members_are_ignored_and_kinds_checked() {
        let o = Object::parse(br#"{"comment":"x","extra":[ ],"value":null,"n":-2.5E-3}"#).expect("an object");
        assert_eq!(o.get("value"), Some(Value::Null));
        assert_eq!(o.get("n"), Some(Value::Number("-2.5E-3")));
        assert_eq!((o.bool("value"), o.str("value"), o.u32("value")), (None, None, None));
        assert!(o.strings("comment").is_none());
        assert_eq!(o.get("absent"), None);
    }
}
