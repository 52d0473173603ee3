//! A TLS target list (`id,x,y,z` CSV).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = pipemeasure::io::tls::parse_targets(std::path::Path::new("tls.csv"), text);
});
