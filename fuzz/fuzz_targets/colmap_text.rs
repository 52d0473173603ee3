//! A COLMAP text model (cameras.txt, images.txt, points3D.txt in one input, separated by
//! `split::SEPARATOR`) through the reader and its reference checks.
#![no_main]

mod split;

use pipemeasure::io::colmap::{ModelFormat, Reconstruction};

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Some(files) = split::three_files(data) {
        let _ = Reconstruction::parse(std::path::Path::new("sparse"), ModelFormat::Text, files);
    }
});
