//! Frame decoding with the product's limits: the first byte picks the size the caller
//! expects — none (any frame up to `MAX_FRAME_PIXELS`), the 64×48 of the seed frames, or a
//! 480×270 model camera — and the rest is the file (PNG, JPEG, TIFF, BMP).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((&mode, bytes)) = data.split_first() else {
        return;
    };
    let expected = match mode % 3 {
        0 => None,
        1 => Some((64, 48)),
        _ => Some((480, 270)),
    };
    let _ = pipemeasure::io::frames::decode_frame(std::path::Path::new("frame"), bytes, expected);
});
