//! `remodaq` against a fake Modbus/TCP server that answers wrongly: short and long replies,
//! another function code, another transaction id, garbage, a dropped connection. Whatever a
//! peer on port 8000 sends, the tool ends with one error line and a documented exit status
//! (6: a reply that does not fit the request; 3: no complete reply in time; 1: connection
//! closed), never a panic.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::time::Duration;

mod common;

/// What the fake server answers to one request frame (MBAP header + PDU); `None` closes the
/// connection.
type Answer = fn(request: &[u8], served: usize) -> Option<Vec<u8>>;

/// A reply frame: the request's transaction id (plus `tid_offset`), protocol 0, unit 1, `pdu`.
fn frame(request: &[u8], tid_offset: u16, pdu: &[u8]) -> Vec<u8> {
    let tid = u16::from_be_bytes([request[0], request[1]]).wrapping_add(tid_offset);
    let mut f = tid.to_be_bytes().to_vec();
    f.extend_from_slice(&[0, 0]);
    f.extend_from_slice(&(pdu.len() as u16 + 1).to_be_bytes());
    f.push(request[6]);
    f.extend_from_slice(pdu);
    f
}

/// The correct answer to a read of holding registers, every register reading `value`.
fn registers(request: &[u8], value: u16) -> Vec<u8> {
    let n = u16::from_be_bytes([request[10], request[11]]);
    let mut pdu = vec![0x03, (2 * n) as u8];
    for _ in 0..n {
        pdu.extend_from_slice(&value.to_be_bytes());
    }
    frame(request, 0, &pdu)
}

/// Serves connections on a loopback port with `answer`, in a thread, until the test ends.
fn fake_server(answer: Answer) -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    std::thread::spawn(move || {
        for stream in listener.incoming().map_while(Result::ok) {
            std::thread::spawn(move || serve(stream, answer));
        }
    });
    addr
}

fn serve(mut stream: TcpStream, answer: Answer) {
    let _ = stream.set_read_timeout(Some(Duration::from_secs(20)));
    for served in 0.. {
        let mut header = [0u8; 7];
        if stream.read_exact(&mut header).is_err() {
            return;
        }
        let len = usize::from(u16::from_be_bytes([header[4], header[5]]));
        let mut pdu = vec![0u8; len.saturating_sub(1)];
        if stream.read_exact(&mut pdu).is_err() {
            return;
        }
        let request = [&header[..], &pdu].concat();
        match answer(&request, served) {
            Some(reply) => {
                if stream.write_all(&reply).is_err() {
                    return;
                }
            }
            None => return,
        }
    }
}

/// Runs the tool: exit status and stderr.
fn remodaq(args: &[&str]) -> (i32, String) {
    let (code, _, stderr) = common::remodaq(args, &[]);
    (code, stderr)
}

/// Every command that talks Modbus, against `answer`: each ends with exit `status` and one
/// error line.
fn every_command_fails(answer: Answer, status: i32, what: &str) {
    let addr = fake_server(answer).to_string();
    let commands: [&[&str]; 4] = [
        &["read", &addr],
        &["--json", "read", &addr],
        &["watch", &addr, "--count", "2", "--interval", "0.1"],
        &["config", &addr, "register", "40201", "0x0F"],
    ];
    for args in commands {
        let mut all = vec!["--timeout", "3"];
        all.extend_from_slice(args);
        let (code, stderr) = remodaq(&all);
        assert_eq!(code, status, "{what}: remodaq {args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{what}: {stderr}");
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{what}: one error line: {stderr}");
        assert!(lines[0].starts_with("error: "), "{what}: {stderr}");
    }
}

#[test]
fn short_replies() {
    // A read of one or more registers answered with none.
    every_command_fails(|r, _| Some(frame(r, 0, &[0x03, 0x00])), 6, "no registers");
    // The identity read answered (8318h), then every read short by one register.
    every_command_fails(
        |r, served| {
            let reply = registers(r, 0x8318);
            if served == 0 {
                return Some(reply);
            }
            let n = u16::from_be_bytes([r[10], r[11]]);
            let mut pdu = vec![0x03, (2 * n - 2) as u8];
            pdu.extend(std::iter::repeat_n(0u8, usize::from(2 * n - 2)));
            Some(frame(r, 0, if r[7] == 0x03 { &pdu } else { &reply[7..] }))
        },
        6,
        "one register short",
    );
    // A frame cut inside the PDU (its length field promises more than is sent): no complete
    // reply within the timeout.
    every_command_fails(|r, _| Some(frame(r, 0, &[0x03, 0x02, 0x83])[..9].to_vec()), 3, "cut frame");
}

#[test]
fn long_replies() {
    every_command_fails(
        |r, _| {
            let n = u16::from_be_bytes([r[10], r[11]]) + 1;
            let mut pdu = vec![0x03, (2 * n) as u8];
            pdu.extend(std::iter::repeat_n(0x83u8, usize::from(2 * n)));
            Some(frame(r, 0, &pdu))
        },
        6,
        "one register too many",
    );
}

#[test]
fn wrong_function_codes() {
    // A read-input-registers reply to a read of holding registers.
    every_command_fails(
        |r, _| {
            let mut reply = registers(r, 0x8318);
            reply[7] = 0x04;
            Some(reply)
        },
        6,
        "function 04 for 03",
    );
}

#[test]
fn wrong_transaction_ids() {
    every_command_fails(
        |r, _| {
            let mut reply = registers(r, 0x8318);
            let tid = u16::from_be_bytes([reply[0], reply[1]]).wrapping_add(7);
            reply[..2].copy_from_slice(&tid.to_be_bytes());
            Some(reply)
        },
        6,
        "another transaction",
    );
}

#[test]
fn garbage() {
    // Read as a Modbus/TCP header, "HTTP/1" promises a frame of 12081 bytes: no complete reply
    // within the timeout.
    every_command_fails(|_, _| Some(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n".to_vec()), 3, "HTTP");
    every_command_fails(
        |r, _| {
            // A header with protocol id 1 and a length of 0.
            let mut reply = frame(r, 0, &[]);
            reply[3] = 1;
            reply[5] = 0;
            Some(reply)
        },
        6,
        "bad header",
    );
}

#[test]
fn dropped_connection() {
    every_command_fails(|_, _| None, 1, "closed without a reply");
}
