//! A device profile (JSON) through parsing and validation, and a valid one through what
//! `profile show` and `profile export` do with it (the distortion check `show` warns from,
//! conversions to COLMAP and OpenCV).
#![no_main]

use pipemeasure::calibrate::checks::check_distortion;
use pipemeasure::camera::convert::{colmap_from_brown, opencv_from_brown, simplest_colmap_model};
use pipemeasure::profile::Profile;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    // The reader takes the file as UTF-8 text (`read_to_string`): other bytes never get here.
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(p) = Profile::from_json(text, std::path::Path::new("fuzz.json")) {
        let _ = check_distortion(&p.intrinsics, (p.image.width, p.image.height));
        let cam = p.camera();
        let _ = colmap_from_brown(&cam, simplest_colmap_model(&cam));
        let _ = opencv_from_brown(&cam);
    }
});
