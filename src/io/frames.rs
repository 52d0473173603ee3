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

/// Reads one frame.
///
/// # Errors
///
/// [`ReadError`] naming the file when it is missing or cannot be decoded.
pub fn read_frame(path: &Path) -> Result<DynamicImage, ReadError> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| open_error(path, e))?
        .with_guessed_format()
        .map_err(|e| ReadError::new(path, ReadErrorKind::Io(e)))?;
    reader
        .decode()
        .map_err(|e| ReadError::new(path, ReadErrorKind::Image(e)))
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
        assert!(e.contains("bad.png") && e.contains("cannot decode"), "{e}");
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
