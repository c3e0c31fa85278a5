//! libmodbus 3.1.6 through its C API, built from source by build.rs: `modbus_reply` answers a
//! request, here into memory (`libmodbus-bench.c`'s backend).

use std::os::raw::{c_int, c_uint, c_void};

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
    fn bench_new_context() -> *mut c_void;
    fn bench_last_answer(out: *mut u8) -> c_int;
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

/// Answers `request` `n` times from a mapping holding `bits` and `registers` (in both tables of
/// each kind); returns the last answer.
pub fn run(request: &[u8], n: u32, bits: &[bool], registers: &[u16]) -> Vec<u8> {
    let size = super::SIZE as c_uint;
    // SAFETY: plain constructor calls; the results are checked for null.
    let (ctx, mapping) =
        unsafe { (bench_new_context(), modbus_mapping_new_start_address(0, size, 0, size, 0, size, 0, size)) };
    if ctx.is_null() || mapping.is_null() {
        eprintln!("libmodbus: no context or mapping");
        return Vec::new();
    }
    // SAFETY: ctx is valid. A response timeout of 1 µs: libmodbus sleeps for it before some
    // exception answers. The mapping's tables hold `size` entries each.
    unsafe {
        modbus_set_response_timeout(ctx, 0, 1);
        let m = &mut *mapping;
        for (i, (&b, &r)) in bits.iter().zip(registers).enumerate().take(super::SIZE) {
            *m.tab_bits.add(i) = u8::from(b);
            *m.tab_input_bits.add(i) = u8::from(b);
            *m.tab_registers.add(i) = r;
            *m.tab_input_registers.add(i) = r;
        }
    }
    let mut sent = 0;
    for _ in 0..n {
        sent = serve_libmodbus(ctx, std::hint::black_box(request), mapping);
    }
    let mut buf = [0u8; 260];
    // SAFETY: the buffer has room for libmodbus's largest TCP ADU (260 bytes).
    let got = unsafe { bench_last_answer(buf.as_mut_ptr()) };
    if got != sent {
        eprintln!("libmodbus: sent {sent} bytes, {got} kept");
    }
    buf[..usize::try_from(got).unwrap_or(0)].to_vec()
}
