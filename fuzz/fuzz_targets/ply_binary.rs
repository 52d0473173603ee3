//! The PLY reader on arbitrary bytes, seeded with binary files, both endians
//! (`corpus/ply_binary`).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pipemeasure::io::ply::parse(std::path::Path::new("fuzz.ply"), data);
});
