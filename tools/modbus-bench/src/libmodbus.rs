//! libmodbus 3.1 (Debian's libmodbus-dev) through its C API: `modbus_reply` answers a request
//! into a socket; here one end of a Unix socket pair, drained after each answer.

use std::io::Read;
use std::os::fd::AsRawFd;
use std::os::raw::{c_char, c_int, c_uint, c_void};
use std::os::unix::net::UnixStream;

#[repr(C)]
pub struct Mapping {
    nb_bits: c_int,
    start_bits: c_int,
    nb_input_bits: c_int,
    start_input_bits: c_int,
    nb_input_registers: c_int,
    start_input_registers: c_int,
    nb_registers: c_int,
    start_registers: c_int,
    tab_bits: *mut u8,
    tab_input_bits: *mut u8,
    tab_input_registers: *mut u16,
    tab_registers: *mut u16,
}

extern "C" {
    fn modbus_new_tcp(ip: *const c_char, port: c_int) -> *mut c_void;
    fn modbus_set_socket(ctx: *mut c_void, s: c_int) -> c_int;
    fn modbus_set_response_timeout(ctx: *mut c_void, sec: u32, usec: u32) -> c_int;
    fn modbus_mapping_new_start_address(
        start_bits: c_uint,
        nb_bits: c_uint,
        start_input_bits: c_uint,
        nb_input_bits: c_uint,
        start_registers: c_uint,
        nb_registers: c_uint,
        start_input_registers: c_uint,
        nb_input_registers: c_uint,
    ) -> *mut Mapping;
    fn modbus_reply(ctx: *mut c_void, req: *const u8, req_length: c_int, mapping: *mut Mapping) -> c_int;
}

/// libmodbus's answer to one frame.
#[inline(never)]
pub fn serve_libmodbus(ctx: *mut c_void, request: &[u8], mapping: *mut Mapping) -> c_int {
    // SAFETY: ctx and mapping come from libmodbus's constructors and live for the run; the
    // request is a whole ADU of the given length.
    unsafe { modbus_reply(ctx, request.as_ptr(), request.len() as c_int, mapping) }
}

/// Answers `request` `n` times; returns the last answer.
pub fn run(request: &[u8], n: u32) -> Vec<u8> {
    let (ours, mut theirs) = UnixStream::pair().expect("socket pair");
    let size = super::SIZE as c_uint;
    // SAFETY: plain constructor calls; the results are checked for null.
    let (ctx, mapping) = unsafe {
        let ctx = modbus_new_tcp(c"127.0.0.1".as_ptr(), 1502);
        let mapping = modbus_mapping_new_start_address(0, size, 0, size, 0, size, 0, size);
        (ctx, mapping)
    };
    assert!(!ctx.is_null() && !mapping.is_null(), "libmodbus constructors");
    // SAFETY: ctx is valid; the socket outlives the run. A response timeout of 1 µs: libmodbus
    // sleeps for it before some exception answers.
    unsafe {
        modbus_set_socket(ctx, ours.as_raw_fd());
        modbus_set_response_timeout(ctx, 0, 1);
        let m = &mut *mapping;
        for i in 0..super::SIZE {
            *m.tab_bits.add(i) = u8::from(super::bit(i));
            *m.tab_input_bits.add(i) = u8::from(super::bit(i));
            *m.tab_registers.add(i) = super::register(i);
            *m.tab_input_registers.add(i) = super::register(i);
        }
    }
    let mut buf = [0u8; 512];
    let mut last = Vec::new();
    for _ in 0..n {
        let sent = serve_libmodbus(ctx, std::hint::black_box(request), mapping);
        let got = theirs.read(&mut buf).expect("answer");
        assert_eq!(sent as usize, got);
        last = buf[..got].to_vec();
    }
    last
}
