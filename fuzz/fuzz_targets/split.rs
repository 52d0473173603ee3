//! Splits one fuzz input into the three files of a COLMAP model.

/// Separates the files in an input (unlikely inside real model files, text or binary).
pub const SEPARATOR: &[u8] = b"\xffPM-FILE\xff";

/// The input cut at [`SEPARATOR`] into exactly three files, or `None`.
pub fn three_files(data: &[u8]) -> Option<[&[u8]; 3]> {
    let mut parts = Vec::with_capacity(3);
    let mut rest = data;
    while let Some(at) = rest.windows(SEPARATOR.len()).position(|w| w == SEPARATOR) {
        parts.push(&rest[..at]);
        rest = &rest[at + SEPARATOR.len()..];
    }
    parts.push(rest);
    match parts[..] {
        [a, b, c] => Some([a, b, c]),
        _ => None,
    }
}
