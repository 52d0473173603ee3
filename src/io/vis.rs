//! COLMAP's `fused.ply.vis`: which images saw each point of a fused dense cloud (written by
//! `colmap stereo_fusion` next to `fused.ply`, COLMAP `src/mvs/fusion.cc`,
//! `WritePointsVisibility`). Little-endian: `u64` number of points, then per point a `u32`
//! count and that many `u32` image indices — positions in the dense workspace's image list,
//! which is the order of the images file of `dense/0/sparse`
//! ([`super::colmap::Reconstruction::image_file_order`]).

use std::path::Path;

use super::atomic::write_bytes_atomic;
use super::error::{ReadError, ReadErrorKind, WriteError, open_error};

/// Reads a visibility file. `expected_points` is the fused cloud's point count, checked.
///
/// # Errors
///
/// [`ReadError`] naming the byte of a truncated or inconsistent record.
pub fn read(path: &Path, expected_points: usize) -> Result<Vec<Vec<u32>>, ReadError> {
    let data = std::fs::read(path).map_err(|e| open_error(path, e))?;
    parse(path, &data, expected_points)
}

/// Parses a visibility file held in memory (`path` only names it in errors).
///
/// # Errors
///
/// As [`read`].
pub fn parse(path: &Path, data: &[u8], expected_points: usize) -> Result<Vec<Vec<u32>>, ReadError> {
    let truncated = |at: usize, what: &str| {
        ReadError::at_byte(path, at as u64, ReadErrorKind::Truncated(what.to_string()))
    };
    let u32_at = |at: usize| -> Option<u32> {
        let b = data.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let Some(head) = data.get(..8) else {
        return Err(truncated(0, "no point count"));
    };
    let mut bytes = [0u8; 8];
    bytes.copy_from_slice(head);
    let n = u64::from_le_bytes(bytes);
    // Every point takes at least its 4-byte count: a count the file cannot hold is a lie.
    if n > (data.len() as u64 - 8) / 4 {
        return Err(ReadError::at_byte(
            path,
            0,
            ReadErrorKind::Invalid(format!(
                "claims {n} points but its {} bytes can hold at most {}",
                data.len(),
                (data.len() - 8) / 4
            )),
        ));
    }
    if n != expected_points as u64 {
        return Err(ReadError::at_byte(
            path,
            0,
            ReadErrorKind::Invalid(format!(
                "has {n} points but the fused cloud has {expected_points}: they do not belong together"
            )),
        ));
    }
    let mut pos = 8;
    let mut out = Vec::with_capacity(n as usize);
    for k in 0..n {
        let count = u32_at(pos).ok_or_else(|| truncated(pos, &format!("point {k}: no count")))?;
        let start = pos + 4;
        let end = start
            .checked_add(4 * count as usize)
            .filter(|&e| e <= data.len())
            .ok_or_else(|| {
                truncated(
                    pos,
                    &format!("point {k}: {count} image indices past the end"),
                )
            })?;
        out.push(
            (start..end)
                .step_by(4)
                .filter_map(u32_at)
                .collect::<Vec<u32>>(),
        );
        pos = end;
    }
    if pos != data.len() {
        return Err(ReadError::at_byte(
            path,
            pos as u64,
            ReadErrorKind::Invalid(format!("{} bytes after the last point", data.len() - pos)),
        ));
    }
    Ok(out)
}

/// Writes a visibility file atomically.
///
/// # Errors
///
/// [`WriteError`] naming the file.
pub fn write(path: &Path, visibility: &[Vec<u32>]) -> Result<(), WriteError> {
    let mut bytes =
        Vec::with_capacity(8 + visibility.iter().map(|v| 4 + 4 * v.len()).sum::<usize>());
    bytes.extend_from_slice(&(visibility.len() as u64).to_le_bytes());
    for v in visibility {
        bytes.extend_from_slice(&(v.len() as u32).to_le_bytes());
        for i in v {
            bytes.extend_from_slice(&i.to_le_bytes());
        }
    }
    write_bytes_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_file_reads_back_and_lies_are_refused() {
        let dir = std::env::temp_dir().join(format!("pm_vis_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("fused.ply.vis");
        let vis = vec![vec![0, 3, 7], vec![], vec![2]];
        write(&path, &vis).unwrap();
        // Known layout: 8 + (4 + 12) + 4 + (4 + 4) bytes.
        assert_eq!(std::fs::metadata(&path).unwrap().len(), 36);
        assert_eq!(read(&path, 3).unwrap(), vis);
        assert!(
            read(&path, 4)
                .unwrap_err()
                .to_string()
                .contains("do not belong")
        );
        // A count of 10¹² points in a 36-byte file.
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[..8].copy_from_slice(&1_000_000_000_000u64.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        assert!(
            read(&path, 3)
                .unwrap_err()
                .to_string()
                .contains("can hold at most")
        );
        // A point whose indices run past the end.
        bytes[..8].copy_from_slice(&3u64.to_le_bytes());
        bytes[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let err = read(&path, 3).unwrap_err().to_string();
        assert!(err.contains("point 0") && err.contains("byte 8"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
