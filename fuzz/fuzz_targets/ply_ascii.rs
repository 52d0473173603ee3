//! The PLY reader on arbitrary bytes, seeded with ascii files (`corpus/ply_ascii`). The reader
//! is the same as `ply_binary`'s; the seeds steer the fuzzer to the ascii body.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pipemeasure::io::ply::parse(std::path::Path::new("fuzz.ply"), data);
});
