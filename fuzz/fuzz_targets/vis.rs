//! COLMAP's `fused.ply.vis`; the first 4 bytes give the point count the fused cloud has.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Some((head, rest)) = data.split_first_chunk::<4>() else {
        return;
    };
    let expected = u32::from_le_bytes(*head) as usize;
    let _ = pipemeasure::io::vis::parse(std::path::Path::new("fused.ply.vis"), rest, expected);
});
