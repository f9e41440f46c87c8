//! Any bytes given to the trace reader produce a trace or an error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = feedloop_trace::Trace::from_reader(
        std::path::Path::new("fuzz.csv"),
        std::io::Cursor::new(data),
    );
});
