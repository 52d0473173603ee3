//! A "Bundle Adjustment in the Large" problem file.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = pipemeasure::io::bal::parse_bal(std::path::Path::new("problem.txt"), text);
});
