//! The simulator's dense observations (`dense/observations.bin`).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pipemeasure::io::observations::DenseObservations::parse(
        std::path::Path::new("observations.bin"),
        data,
    );
});
