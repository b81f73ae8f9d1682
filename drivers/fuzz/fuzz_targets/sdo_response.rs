//! CANopen SDO response and upload segment parsers.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = calibd_drivers::can::canopen::parse_response(data);
    let _ = calibd_drivers::can::canopen::parse_upload_segment(data, data.first() == Some(&0x10));
});
