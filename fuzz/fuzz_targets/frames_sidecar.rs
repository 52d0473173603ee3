//! The frames sidecar `frames/frames.json` (`calibrate` reads it for the frames' neighbours in
//! the video), through parsing and validation, and a valid one through the lookup `calibrate`
//! makes.
#![no_main]

use pipemeasure::io::sidecar::FramesSidecar;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    // The reader takes the file as UTF-8 text (`read_to_string`): other bytes never get here.
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(s) = FramesSidecar::parse(text, std::path::Path::new("frames.json")) {
        if let Some(first) = s.frames.first() {
            let _ = s.neighbours_of(&first.name);
        }
    }
});
