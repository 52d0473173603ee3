//! An E57 scan through the `e57` crate (header, XML, paged CRC blocks, bit-packed records) and
//! our reader around it.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pipemeasure::io::e57::parse(std::path::Path::new("fuzz.e57"), data);
});
