//! The broker's TLS records on their way to embedded-tls 0.19, whose record layer a peer can
//! make panic and which a dropped read leaves in the middle of a record (reviews of this round,
//! reading its source): [`Guarded`] ends the connection at a record no TLS 1.3 server sends;
//! [`Whole`] hands it whole records only, where the caller drops reads (the simulator's session).

use embedded_io_async::{Error as _, Read, Write};

/// The broker's bytes on their way to embedded-tls, their records' headers read as they pass
/// (RFC 8446 §5): two kinds of record that no TLS 1.3 server sends, and on which embedded-tls
/// 0.19 panics, end the connection before it sees them (reviews of this round, reading its
/// source; a panic is a reset of the module):
/// - an encrypted record (`application_data`) shorter than the AEAD's tag and the inner content
///   type, 17 bytes: on one of 16 (a tag over nothing) `decrypt_record` unwraps the last byte
///   of an empty plaintext; whoever holds the handshake's keys can send it (a man in the
///   middle, before the certificate is checked);
/// - a handshake record in clear after the first (the ServerHello; embedded-tls does no
///   HelloRetryRequest, and every later handshake message is encrypted): once the connection
///   is open, its reader meets any handshake message but a NewSessionTicket with
///   an `unimplemented` panic, and 11 bytes injected into the TCP stream, no key needed, make one.
#[derive(Clone)]
pub struct Guarded<T> {
    inner: T,
    /// The record header being read, and how many of its bytes came.
    header: [u8; HEADER],
    have: usize,
    /// The bytes of the current record's body still to come.
    body: usize,
    /// Whether the handshake record in clear (the ServerHello) came.
    hello: bool,
}

impl<T> Guarded<T> {
    /// `inner`'s bytes, guarded from its first record on.
    pub fn new(inner: T) -> Self {
        Guarded { inner, header: [0; HEADER], have: 0, body: 0, hello: false }
    }

    /// Follows the records through `bytes`: `false` at a record no TLS 1.3 peer sends.
    fn pass(&mut self, mut bytes: &[u8]) -> bool {
        while !bytes.is_empty() {
            if self.body > 0 {
                let n = self.body.min(bytes.len());
                self.body -= n;
                bytes = &bytes[n..];
                continue;
            }
            self.header[self.have] = bytes[0];
            self.have += 1;
            bytes = &bytes[1..];
            if self.have == self.header.len() {
                self.have = 0;
                self.body = body_length(&self.header);
                match self.header[0] {
                    APPLICATION_DATA if self.body < MIN_ENCRYPTED => return false,
                    HANDSHAKE if self.hello => return false,
                    HANDSHAKE => self.hello = true,
                    _ => {}
                }
            }
        }
        true
    }
}

/// A record header's bytes: content type, version, body length.
const HEADER: usize = 5;

/// The body length a record header gives (RFC 8446 §5.1: its last two bytes, big-endian).
fn body_length(header: &[u8; HEADER]) -> usize {
    usize::from(u16::from_be_bytes([header[3], header[4]]))
}

/// TLS's content type of an encrypted record.
const APPLICATION_DATA: u8 = 23;
/// TLS's content type of a handshake record in clear.
const HANDSHAKE: u8 = 22;
/// The shortest encrypted record: the inner content type and AES-GCM's 16-byte tag.
const MIN_ENCRYPTED: usize = 17;

// A guarded read's error: the transport's kind, or `InvalidData` for a refused record.
impl<T: embedded_io_async::ErrorType> embedded_io_async::ErrorType for Guarded<T> {
    type Error = embedded_io_async::ErrorKind;
}

impl<T: Read> Read for Guarded<T> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = self.inner.read(buf).await.map_err(|e| e.kind())?;
        if self.pass(buf.get(..n).unwrap_or_default()) {
            Ok(n)
        } else {
            Err(embedded_io_async::ErrorKind::InvalidData)
        }
    }
}

impl<T: Write> Write for Guarded<T> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.inner.write(buf).await.map_err(|e| e.kind())
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        self.inner.flush().await.map_err(|e| e.kind())
    }
}

/// A transport that hands embedded-tls whole records only. Its record reader is not safe to
/// drop in the middle of a record: the next read would take a header from the middle of the
/// old one, whose length can then index past its buffer (a panic). The session drops reads at
/// each look (`select` with its ticker) over TLS run in its own task (`crate::service`); here a
/// read waits, and may be dropped, only while no whole record has come, and then nothing of one
/// was handed on: every byte that came stays here.
pub struct Whole<T, const N: usize> {
    inner: T,
    /// Room for the longest record taken, its header with it (`crate::tls::WHOLE`).
    buf: [u8; N],
    /// What came and was not handed on: `buf[start..end]`, whole records to `ready`.
    start: usize,
    ready: usize,
    end: usize,
}

impl<T, const N: usize> Whole<T, N> {
    /// Over `inner`.
    pub fn new(inner: T) -> Self {
        Whole { inner, buf: [0; N], start: 0, ready: 0, end: 0 }
    }

    /// Moves `ready` past every whole record that came.
    fn find_records(&mut self) {
        while let Some(Ok(header)) =
            self.buf[..self.end].get(self.ready..self.ready + HEADER).map(<&[u8; HEADER]>::try_from)
        {
            let record = HEADER + body_length(header);
            if self.ready + record > self.end {
                break;
            }
            self.ready += record;
        }
    }
}

impl<T: embedded_io_async::ErrorType, const N: usize> embedded_io_async::ErrorType for Whole<T, N> {
    type Error = embedded_io_async::ErrorKind;
}

impl<T: Read, const N: usize> Read for Whole<T, N> {
    async fn read(&mut self, out: &mut [u8]) -> Result<usize, Self::Error> {
        loop {
            if self.ready > self.start {
                let n = out.len().min(self.ready - self.start);
                out[..n].copy_from_slice(&self.buf[self.start..self.start + n]);
                self.start += n;
                return Ok(n);
            }
            // Nothing whole yet: the rest to the front, then more.
            self.buf.copy_within(self.start..self.end, 0);
            (self.ready, self.end) = (self.ready - self.start, self.end - self.start);
            self.start = 0;
            if self.end == self.buf.len() {
                // A record longer than the module asked the broker for.
                return Err(embedded_io_async::ErrorKind::InvalidData);
            }
            let n = self.inner.read(&mut self.buf[self.end..]).await.map_err(|e| e.kind())?;
            if n == 0 {
                return Ok(0);
            }
            self.end += n;
            self.find_records();
        }
    }
}

impl<T: Write, const N: usize> Write for Whole<T, N> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.inner.write(buf).await.map_err(|e| e.kind())
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        self.inner.flush().await.map_err(|e| e.kind())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RFC 8446 §5.2's records: a header of type, version and length, then the body.
    #[test]
    fn an_encrypted_record_shorter_than_its_tag_and_type_is_refused() {
        let mut g = Guarded::new(());
        // A handshake record of 2 bytes, then application data of 17 (the shortest there is).
        assert!(g.pass(&[22, 3, 3, 0, 2, 1, 2]));
        let mut record = std::vec![23, 3, 3, 0, 17];
        record.extend_from_slice(&[0xAA; 17]);
        assert!(g.pass(&record));
        // Its header split over three reads, its body over two: still followed.
        assert!(g.pass(&[23, 3]) && g.pass(&[3, 0]) && g.pass(&[20, 0]) && g.pass(&[0; 19]));
        // 16 bytes: a tag alone (embedded-tls 0.19 panics on it once decrypted); and 0.
        assert!(!g.pass(&[23, 3, 3, 0, 16]));
        assert!(!Guarded::new(()).pass(&[23, 3, 3, 0, 0]));
        // An alert in clear of 2 bytes, a change_cipher_spec of 1: not encrypted, passed on.
        assert!(Guarded::new(()).pass(&[21, 3, 3, 0, 2, 2, 40, 20, 3, 3, 0, 1, 1]));
    }

    /// One handshake record in clear, the ServerHello; another (here the review's 11 bytes, an
    /// EncryptedExtensions in clear) ends the connection, even split over reads.
    #[test]
    fn a_second_handshake_record_in_clear_is_refused() {
        let mut g = Guarded::new(());
        assert!(g.pass(&[22, 3, 3, 0, 4, 2, 0, 0, 0]));
        assert!(g.pass(&[20, 3, 3, 0, 1, 1, 23, 3, 3, 0, 17]) && g.pass(&[0; 17]));
        assert!(!g.pass(&[22, 3, 3, 0, 6, 8, 0, 0, 0, 0, 0]));
        let mut g = Guarded::new(());
        assert!(g.pass(&[22, 3, 3, 0, 1, 2]) && g.pass(&[22, 3]));
        assert!(!g.pass(&[3, 0, 6]));
    }

    /// A reader of the chunks given, then of nothing (the end; or, with `.1`, it waits).
    struct Chunks(std::vec::Vec<std::vec::Vec<u8>>, bool);

    impl embedded_io_async::ErrorType for Chunks {
        type Error = embedded_io_async::ErrorKind;
    }

    impl Read for Chunks {
        async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
            if self.0.is_empty() {
                if self.1 {
                    core::future::pending::<()>().await;
                }
                return Ok(0);
            }
            let chunk = self.0.remove(0);
            let n = chunk.len().min(buf.len());
            buf[..n].copy_from_slice(&chunk[..n]);
            if n < chunk.len() {
                self.0.insert(0, chunk[n..].to_vec());
            }
            Ok(n)
        }
    }

    /// Records split over the transport's reads come out whole, each byte once and in order;
    /// a record longer than the buffer is refused.
    #[test]
    fn only_whole_records_are_handed_on() {
        let a = [23, 3, 3, 0, 3, 1, 2, 3];
        let b = [23, 3, 3, 0, 2, 4, 5];
        let chunks = std::vec![a[..2].to_vec(), [&a[2..], &b[..6]].concat(), b[6..].to_vec()];
        let mut whole = Whole::new(Chunks(chunks, false));
        let mut out = [0u8; 64];
        let read = |w: &mut Whole<Chunks, 64>, out: &mut [u8]| futures_executor::block_on(w.read(out));
        assert_eq!(read(&mut whole, &mut out), Ok(8));
        assert_eq!(out[..8], a);
        // A caller's buffer smaller than the record: the rest at the next read, at once.
        assert_eq!(read(&mut whole, &mut out[..3]), Ok(3));
        assert_eq!(read(&mut whole, &mut out[3..]), Ok(4));
        assert_eq!(out[..7], b);
        assert_eq!(read(&mut whole, &mut out), Ok(0));

        let long = std::vec![[23, 3, 3, 0, 60].to_vec(), std::vec![0; 60]];
        assert_eq!(
            read(&mut Whole::new(Chunks(long, false)), &mut out),
            Err(embedded_io_async::ErrorKind::InvalidData)
        );
    }

    /// A read that waits for the rest of a record, dropped (the session's tick), loses nothing:
    /// the next one hands the record on whole.
    #[test]
    fn a_read_dropped_before_its_record_is_whole_loses_nothing() {
        let mut whole = Whole::<_, 64>::new(Chunks(std::vec![std::vec![23, 3, 3, 0, 3, 1]], true));
        let mut out = [0u8; 16];
        assert!(embassy_futures::poll_once(whole.read(&mut out)).is_pending());
        whole.inner.0.push(std::vec![2, 3]);
        assert_eq!(futures_executor::block_on(whole.read(&mut out)), Ok(8));
        assert_eq!(out[..8], [23, 3, 3, 0, 3, 1, 2, 3]);
    }
}
