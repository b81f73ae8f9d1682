//! CANopen SDO response parser.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = calibd_drivers::can::canopen::parse_response(data);
});
