//! Any bytes given to the trace reader produce a trace or an error, never a panic.

fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = feedloop_trace::Trace::from_reader(
            std::path::Path::new("fuzz.csv"),
            std::io::Cursor::new(data),
        );
    });
}
