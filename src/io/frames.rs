//! Video frames on disk: listing a folder of PNG/JPEG/TIFF/BMP images in name order, reading
//! one with errors that name the file, and writing losslessly (PNG).

use std::path::{Path, PathBuf};

use image::DynamicImage;

use super::atomic::write_atomic;
use super::error::{ReadError, ReadErrorKind, WriteError, open_error};

/// File extensions treated as frames (case-insensitive).
pub const FRAME_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "tif", "tiff", "bmp"];

/// Whether a path has a frame extension.
#[must_use]
pub fn is_frame(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| FRAME_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// The frames of a folder, sorted by file name.
///
/// # Errors
///
/// [`ReadError`] when the folder is missing or unreadable, or holds no frames.
pub fn list_frames(dir: &Path) -> Result<Vec<PathBuf>, ReadError> {
    if !dir.exists() {
        return Err(ReadError::new(dir, ReadErrorKind::NotFound));
    }
    if !dir.is_dir() {
        return Err(ReadError::new(
            dir,
            ReadErrorKind::Invalid("not a directory".into()),
        ));
    }
    let entries = std::fs::read_dir(dir).map_err(|e| open_error(dir, e))?;
    let mut frames = Vec::new();
    for entry in entries {
        let path = entry
            .map_err(|e| ReadError::new(dir, ReadErrorKind::Io(e)))?
            .path();
        if path.is_file() && is_frame(&path) {
            frames.push(path);
        }
    }
    if frames.is_empty() {
        return Err(ReadError::new(
            dir,
            ReadErrorKind::Invalid(format!(
                "no frames (files ending in {})",
                FRAME_EXTENSIONS.map(|e| format!(".{e}")).join(", ")
            )),
        ));
    }
    frames.sort();
    Ok(frames)
}

/// The most pixels a frame may have (10⁸: a 100-megapixel photo, three 8K video frames): the
/// decoder is never asked for more, and an SfM camera larger than this is refused.
pub const MAX_FRAME_PIXELS: u64 = 100_000_000;

/// The longest side a frame may have (px; JPEG's own limit).
pub const MAX_FRAME_SIDE_PX: u32 = 65_535;

/// The most bytes a decoded pixel takes (RGBA with 16 bits per channel).
const MAX_BYTES_PER_PIXEL: u64 = 8;

/// Room for a decoder's own buffers beside the decoded frame (bytes).
const DECODER_SLACK_BYTES: u64 = 16 << 20;

/// Reads one frame of any size up to [`MAX_FRAME_PIXELS`].
///
/// # Errors
///
/// As [`decode_frame`], plus a missing or unreadable file.
pub fn read_frame(path: &Path) -> Result<DynamicImage, ReadError> {
    read_frame_sized(path, None)
}

/// Reads one frame that must be `expected` = (width, height) when given (the SfM model's or the
/// profile's frame size): the size is read from the file's header and checked before anything
/// is decoded, and the decoder may allocate only what a frame of that size needs.
///
/// # Errors
///
/// As [`decode_frame`], plus a missing or unreadable file.
pub fn read_frame_sized(
    path: &Path,
    expected: Option<(u32, u32)>,
) -> Result<DynamicImage, ReadError> {
    let bytes = std::fs::read(path).map_err(|e| open_error(path, e))?;
    decode_frame(path, &bytes, expected)
}

/// The size of a frame from its header, without decoding it.
///
/// # Errors
///
/// [`ReadError`] naming the file: missing, not an image, or a header that does not parse.
pub fn frame_size(path: &Path) -> Result<(u32, u32), ReadError> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| open_error(path, e))?
        .with_guessed_format()
        .map_err(|e| open_error(path, e))?;
    if reader.format().is_none() {
        return Err(ReadError::new(
            path,
            ReadErrorKind::WrongFormat("PNG, JPEG, TIFF or BMP"),
        ));
    }
    reader
        .into_dimensions()
        .map_err(|e| ReadError::new(path, ReadErrorKind::Image(e)))
}

/// A frame and the size its header gives.
pub type SizedFrame<'a> = (&'a Path, (u32, u32));

/// The first of `paths` whose header gives another size than `size`, with that size: every
/// frame checked from its header before any is decoded.
///
/// # Errors
///
/// As [`frame_size`], for the first file whose header cannot be read.
pub fn first_of_another_size(
    paths: &[PathBuf],
    size: (u32, u32),
) -> Result<Option<SizedFrame<'_>>, ReadError> {
    for path in paths {
        let found = frame_size(path)?;
        if found != size {
            return Ok(Some((path, found)));
        }
    }
    Ok(None)
}

/// Decodes a frame held in memory (`path` names it in errors) with the product's limits: the
/// size in the header is checked first — against `expected` when given, otherwise against
/// [`MAX_FRAME_PIXELS`] — and the decoder's memory limit is what a frame of that size needs; a
/// JPEG must end with its end-of-image marker (a truncated JPEG decodes without complaint,
/// its missing part grey).
///
/// # Errors
///
/// [`ReadError`] naming the file: not an image, another size than expected, too many pixels,
/// truncated, or a decoder error.
pub fn decode_frame(
    path: &Path,
    bytes: &[u8],
    expected: Option<(u32, u32)>,
) -> Result<DynamicImage, ReadError> {
    let reader = |limits: image::Limits| {
        let mut r = image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| ReadError::new(path, ReadErrorKind::Io(e)))?;
        let format = r.format().ok_or_else(|| {
            ReadError::new(path, ReadErrorKind::WrongFormat("PNG, JPEG, TIFF or BMP"))
        })?;
        r.limits(limits);
        Ok::<_, ReadError>((r, format))
    };
    let image_error = |e| ReadError::new(path, ReadErrorKind::Image(e));
    // The header's size, with the decoder allowed nothing beyond its own header buffers.
    let mut header_limits = image::Limits::default();
    header_limits.max_alloc = Some(DECODER_SLACK_BYTES);
    let (r, format) = reader(header_limits)?;
    let (w, h) = r.into_dimensions().map_err(image_error)?;
    match expected {
        Some((ew, eh)) if (w, h) != (ew, eh) => {
            return Err(ReadError::new(
                path,
                ReadErrorKind::Invalid(format!("the frame is {w}x{h}, expected {ew}x{eh}")),
            ));
        }
        None if u64::from(w) * u64::from(h) > MAX_FRAME_PIXELS || w.max(h) > MAX_FRAME_SIDE_PX => {
            return Err(ReadError::new(
                path,
                ReadErrorKind::Invalid(format!(
                    "the frame is {w}x{h}: more than the {MAX_FRAME_PIXELS} pixels (or a side longer than {MAX_FRAME_SIDE_PX} px) a frame may have"
                )),
            ));
        }
        _ => {}
    }
    if format == image::ImageFormat::Jpeg && !jpeg_is_complete(bytes) {
        return Err(ReadError::new(
            path,
            ReadErrorKind::Truncated("the JPEG data stop before the end-of-image marker".into()),
        ));
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(w);
    limits.max_image_height = Some(h);
    limits.max_alloc =
        Some(u64::from(w) * u64::from(h) * MAX_BYTES_PER_PIXEL + DECODER_SLACK_BYTES);
    let (r, _) = reader(limits)?;
    r.decode().map_err(image_error)
}

/// Whether a JPEG stream reaches its end-of-image marker: the marker segments are walked by
/// their lengths and each scan's entropy-coded data to the next marker (in it, 0xFF is followed
/// by a stuffed 0x00 or a restart marker), so an EOI inside an embedded thumbnail or a table
/// does not count.
fn jpeg_is_complete(b: &[u8]) -> bool {
    if !b.starts_with(&[0xFF, 0xD8]) {
        return false;
    }
    let mut i = 2;
    loop {
        if b.get(i) != Some(&0xFF) {
            return false;
        }
        while b.get(i) == Some(&0xFF) {
            i += 1;
        }
        let Some(&marker) = b.get(i) else {
            return false;
        };
        i += 1;
        match marker {
            0xD9 => return true,
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        let Some(len) = b
            .get(i..i + 2)
            .map(|l| usize::from(u16::from_be_bytes([l[0], l[1]])))
        else {
            return false;
        };
        if len < 2 {
            return false;
        }
        i += len;
        if marker == 0xDA {
            // Entropy-coded data up to the next marker.
            loop {
                let Some(j) = b.get(i..).and_then(|s| s.iter().position(|&x| x == 0xFF)) else {
                    return false;
                };
                let j = i + j;
                match b.get(j + 1) {
                    None => return false,
                    Some(0x00 | 0xD0..=0xD7) => i = j + 2,
                    Some(0xFF) => i = j + 1,
                    Some(_) => {
                        i = j;
                        break;
                    }
                }
            }
        }
    }
}

/// Writes a frame as PNG (lossless), atomically.
///
/// # Errors
///
/// [`WriteError`] naming the file.
pub fn write_png(path: &Path, frame: &DynamicImage) -> Result<(), WriteError> {
    write_atomic(path, |w| {
        let encoder = image::codecs::png::PngEncoder::new_with_quality(
            w,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Adaptive,
        );
        frame
            .write_with_encoder(encoder)
            .map_err(std::io::Error::other)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_frames_sorted_and_ignores_others() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["b.PNG", "a.jpg", "notes.txt", "c.jpeg"] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        let names: Vec<_> = list_frames(dir.path())
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["a.jpg", "b.PNG", "c.jpeg"]);
    }

    #[test]
    fn missing_empty_and_undecodable_are_errors() {
        let e = list_frames(Path::new("/nonexistent/frames"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/frames: not found"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let e = list_frames(dir.path()).unwrap_err().to_string();
        assert!(e.contains("no frames"), "{e}");
        let bad = dir.path().join("bad.png");
        std::fs::write(&bad, b"not an image").unwrap();
        let e = read_frame(&bad).unwrap_err().to_string();
        assert!(
            e.contains("bad.png") && e.contains("not a PNG, JPEG, TIFF or BMP file"),
            "{e}"
        );
    }

    /// A noisy 64×48 RGB frame, encoded in `format`.
    fn encoded(format: image::ImageFormat) -> Vec<u8> {
        let img = DynamicImage::ImageRgb8(image::ImageBuffer::from_fn(64, 48, |x, y| {
            let v = (x * 7 + y * 13 + (x * y) % 17) as u8;
            image::Rgb([v, v.wrapping_mul(3), 255 - v])
        }));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, format).unwrap();
        out.into_inner()
    }

    /// A PNG whose header claims `w`×`h` (8-bit grey) with a token IDAT: the size is all that
    /// matters before decoding.
    fn png_claiming(w: u32, h: u32) -> Vec<u8> {
        fn crc32(bytes: &[u8]) -> u32 {
            let mut c = 0xFFFF_FFFFu32;
            for &b in bytes {
                c ^= u32::from(b);
                for _ in 0..8 {
                    c = if c & 1 == 1 {
                        0xEDB8_8320 ^ (c >> 1)
                    } else {
                        c >> 1
                    };
                }
            }
            !c
        }
        let chunk = |kind: &[u8], data: &[u8]| {
            let mut c = (data.len() as u32).to_be_bytes().to_vec();
            let body: Vec<u8> = kind.iter().chain(data).copied().collect();
            c.extend(&body);
            c.extend(crc32(&body).to_be_bytes());
            c
        };
        let mut ihdr = w.to_be_bytes().to_vec();
        ihdr.extend(h.to_be_bytes());
        ihdr.extend([8, 0, 0, 0, 0]);
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        png.extend(chunk(b"IHDR", &ihdr));
        png.extend(chunk(
            b"IDAT",
            &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
        ));
        png.extend(chunk(b"IEND", &[]));
        png
    }

    #[test]
    fn every_format_decodes_with_the_expected_size() {
        use image::ImageFormat::{Bmp, Jpeg, Png, Tiff};
        for format in [Png, Jpeg, Bmp, Tiff] {
            let bytes = encoded(format);
            let f = decode_frame(Path::new("f"), &bytes, Some((64, 48))).unwrap();
            assert_eq!((f.width(), f.height()), (64, 48), "{format:?}");
        }
    }

    /// A 249 KB PNG that decodes to 16000×16000 cost 2.2 GB per frame; frames of
    /// another size than the model's were used silently.
    #[test]
    fn frame_size_is_checked_before_decoding() {
        let png = png_claiming(16_000, 16_000);
        let e = decode_frame(Path::new("big.png"), &png, Some((960, 540))).unwrap_err();
        assert_eq!(
            e.to_string(),
            "big.png: the frame is 16000x16000, expected 960x540"
        );
        let e = decode_frame(Path::new("big.png"), &png, None).unwrap_err();
        assert!(
            e.to_string().contains("more than the 100000000 pixels"),
            "{e}"
        );
        let e = decode_frame(
            Path::new("f.bmp"),
            &encoded(image::ImageFormat::Bmp),
            Some((48, 64)),
        )
        .unwrap_err();
        assert_eq!(e.to_string(), "f.bmp: the frame is 64x48, expected 48x64");
    }

    /// A truncated JPEG (the first third of a frame) was accepted, its missing part
    /// grey.
    #[test]
    fn truncated_frames_are_errors() {
        use image::ImageFormat::{Bmp, Jpeg, Png, Tiff};
        for format in [Jpeg, Png, Bmp, Tiff] {
            let bytes = encoded(format);
            let cut = &bytes[..bytes.len() / 3];
            let e = decode_frame(Path::new("cut"), cut, Some((64, 48)));
            assert!(e.is_err(), "{format:?} cut to a third decoded");
        }
        let bytes = encoded(Jpeg);
        let e = decode_frame(Path::new("cut.jpg"), &bytes[..bytes.len() / 3], None).unwrap_err();
        assert!(
            e.to_string()
                .contains("stop before the end-of-image marker"),
            "{e}"
        );
        // The whole file passes, and so does one with bytes after the end-of-image marker.
        let mut tail = bytes.clone();
        tail.extend(b"trailer");
        decode_frame(Path::new("tail.jpg"), &tail, None).unwrap();
        assert!(!jpeg_is_complete(&bytes[..bytes.len() - 1]));
    }

    #[test]
    fn png_round_trip_is_lossless() {
        let dir = tempfile::tempdir().unwrap();
        let img = DynamicImage::ImageRgb8(image::ImageBuffer::from_fn(7, 5, |x, y| {
            image::Rgb([x as u8 * 30, y as u8 * 50, (x * y) as u8])
        }));
        let p = dir.path().join("f.png");
        write_png(&p, &img).unwrap();
        assert_eq!(read_frame(&p).unwrap(), img);
    }
}
