//! A session's reads and writes, each bounded by [`STALL`]: bytes and signed statuses sent,
//! bytes read.

use embassy_time::{with_timeout, Duration};
use embedded_io_async::{Read, Write};

use remodaq_protocol::update::{Status, HANDSHAKE_S, SIGNED_ANSWER_LEN};
use remodaq_shared::password::KEY_LEN;

/// A session whose peer sends nothing for this long ends (the image stays unmarked).
pub const STALL: Duration = Duration::from_secs(HANDSHAKE_S);

/// Sends a status and its signature; false if it could not be sent in time.
pub(crate) async fn send_signed<T: Write>(io: &mut T, status: Status, signature: &[u8; KEY_LEN]) -> bool {
    let mut bytes = [0u8; SIGNED_ANSWER_LEN];
    bytes[0] = status as u8;
    bytes[1..].copy_from_slice(signature);
    send(io, &bytes).await
}

/// Sends bytes; false if they could not be sent in time.
pub(crate) async fn send<T: Write>(io: &mut T, bytes: &[u8]) -> bool {
    let sent = with_timeout(STALL, async {
        io.write_all(bytes).await?;
        io.flush().await
    })
    .await;
    let ok = matches!(sent, Ok(Ok(())));
    if !ok {
        remodaq_shared::warn!("update: the answer could not be sent");
    }
    ok
}

/// Fills `buf`; `None` if the peer closed, failed or stalled first.
pub(crate) async fn read_exact<T: Read>(io: &mut T, buf: &mut [u8]) -> Option<()> {
    let mut filled = 0;
    while filled < buf.len() {
        match with_timeout(STALL, io.read(&mut buf[filled..])).await {
            Ok(Ok(n)) if n > 0 => filled += n,
            _ => return None,
        }
    }
    Some(())
}
