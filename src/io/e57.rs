//! E57 point clouds (ASTM E2807, the format terrestrial laser scanners export), read with the
//! pure-Rust `e57` crate: every scan of the file, its pose applied (each scan's points in the
//! file's common coordinate system), spherical coordinates converted to Cartesian, invalid
//! points left out. Returns the same [`PlyRead`] as the PLY reader so callers need not care.

use std::path::Path;

use nalgebra::Point3;

use super::error::{ReadError, ReadErrorKind, open_file};
use super::ply::{PlyRead, PointCloud, StreamSummary};

/// Reads every scan of an E57 file into one cloud (colours and intensity are not kept).
///
/// # Errors
///
/// [`ReadError`] naming the file: missing, not E57, corrupt, or a scan without coordinates.
pub fn read(path: &Path) -> Result<PlyRead, ReadError> {
    let file = open_file(path)?;
    read_from(path, std::io::BufReader::new(file))
}

/// Reads an E57 file held in memory; `path` only names it in errors.
///
/// # Errors
///
/// As [`read`].
pub fn parse(path: &Path, bytes: &[u8]) -> Result<PlyRead, ReadError> {
    read_from(path, std::io::Cursor::new(bytes))
}

/// Reads every scan of the E57 data in `source`.
fn read_from<T: std::io::Read + std::io::Seek>(
    path: &Path,
    source: T,
) -> Result<PlyRead, ReadError> {
    let mut points = Vec::new();
    let summary = each_point(path, source, &mut |p| points.push(p))?;
    Ok(PlyRead {
        cloud: PointCloud::from_points(points),
        vertices_in_file: summary.vertices_in_file,
        skipped_non_finite: summary.skipped_non_finite,
    })
}

/// Reads the points of every scan of an E57 file in chunks of at most `chunk` points, each
/// handed to `f` in file order and then forgotten (the streamed twin of [`read`]). An error
/// comes after some chunks were handed on: the caller must discard what it built from them.
///
/// # Errors
///
/// As [`read`].
pub fn stream(
    path: &Path,
    chunk: usize,
    f: &mut dyn FnMut(&[Point3<f64>]),
) -> Result<StreamSummary, ReadError> {
    let file = open_file(path)?;
    let chunk = chunk.max(1);
    let mut buf = Vec::with_capacity(chunk.min(1 << 20));
    let summary = each_point(path, std::io::BufReader::new(file), &mut |p| {
        buf.push(p);
        if buf.len() >= chunk {
            f(&buf);
            buf.clear();
        }
    })?;
    if !buf.is_empty() {
        f(&buf);
    }
    Ok(summary)
}

/// Hands every valid point of every scan of the E57 data in `source` to `f`, in the file's
/// common coordinate system.
fn each_point<T: std::io::Read + std::io::Seek>(
    path: &Path,
    source: T,
    f: &mut dyn FnMut(Point3<f64>),
) -> Result<StreamSummary, ReadError> {
    let invalid = |e: e57::Error| ReadError::new(path, ReadErrorKind::Invalid(format!("E57: {e}")));
    let mut reader = e57::E57Reader::new(source).map_err(invalid)?;
    let mut summary = StreamSummary::default();
    for (k, pc) in reader.pointclouds().iter().enumerate() {
        let scan = reader.pointcloud_simple(pc).map_err(invalid)?;
        for p in scan {
            let p = p.map_err(|e| {
                ReadError::new(path, ReadErrorKind::Invalid(format!("E57 scan {k}: {e}")))
            })?;
            summary.vertices_in_file += 1;
            match p.cartesian {
                e57::CartesianCoordinate::Valid { x, y, z }
                    if x.is_finite() && y.is_finite() && z.is_finite() =>
                {
                    f(Point3::new(x, y, z));
                }
                _ => summary.skipped_non_finite += 1,
            }
        }
    }
    Ok(summary)
}

/// Streams the points of a cloud by its extension, as [`read_cloud`] reads them: `.e57`
/// through [`stream`], anything else through [`super::ply::stream_points`].
///
/// # Errors
///
/// [`ReadError`] of the reader.
pub fn stream_cloud(
    path: &Path,
    chunk: usize,
    f: &mut dyn FnMut(&[Point3<f64>]),
) -> Result<StreamSummary, ReadError> {
    if is_e57(path) {
        stream(path, chunk, f)
    } else {
        super::ply::stream_points(path, chunk, f)
    }
}

/// The number of points a cloud's file declares (PLY: its header's vertex count; E57: the
/// records of all its scans), without reading them: a caller's estimate, checked when the
/// points are read.
///
/// # Errors
///
/// [`ReadError`] of the reader, for the header.
pub fn declared_points(path: &Path) -> Result<u64, ReadError> {
    if !is_e57(path) {
        return super::ply::vertex_count(path);
    }
    let invalid = |e: e57::Error| ReadError::new(path, ReadErrorKind::Invalid(format!("E57: {e}")));
    let reader = e57::E57Reader::new(std::io::BufReader::new(open_file(path)?)).map_err(invalid)?;
    Ok(reader
        .pointclouds()
        .iter()
        .fold(0u64, |n, pc| n.saturating_add(pc.records)))
}

/// Whether `path` names an E57 file (by its extension, in any case).
fn is_e57(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("e57"))
}

/// Reads the points of a cloud by its extension: `.e57` through [`read`], anything else as PLY
/// through [`super::ply::read_points`] (coordinates only, as measuring needs).
///
/// # Errors
///
/// [`ReadError`] of the reader.
pub fn read_cloud(path: &Path) -> Result<PlyRead, ReadError> {
    if is_e57(path) {
        read(path)
    } else {
        super::ply::read_points(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use e57::{E57Writer, Quaternion, Record, RecordValue, Transform, Translation};

    /// Writes two scans: one at the origin, one under a pose (90° about z, shifted), with one
    /// point that is not finite.
    fn write_two_scans(path: &Path) {
        let mut w = E57Writer::from_file(path, "pipemeasure-test").unwrap();
        let prototype = vec![
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
        ];
        {
            let mut pc = w.add_pointcloud("scan-a", prototype.clone()).unwrap();
            for (x, y, z) in [(1.0, 2.0, 3.0), (4.5e5, 5.1e6, 12.0), (f64::NAN, 0.0, 0.0)] {
                pc.add_point(vec![
                    RecordValue::Double(x),
                    RecordValue::Double(y),
                    RecordValue::Double(z),
                ])
                .unwrap();
            }
            pc.finalize().unwrap();
        }
        {
            let mut pc = w.add_pointcloud("scan-b", prototype).unwrap();
            let half = std::f64::consts::FRAC_1_SQRT_2;
            pc.set_transform(Some(Transform {
                rotation: Quaternion {
                    w: half,
                    x: 0.0,
                    y: 0.0,
                    z: half,
                },
                translation: Translation {
                    x: 10.0,
                    y: 0.0,
                    z: 1.0,
                },
            }));
            pc.add_point(vec![
                RecordValue::Double(1.0),
                RecordValue::Double(0.0),
                RecordValue::Double(0.0),
            ])
            .unwrap();
            pc.finalize().unwrap();
        }
        w.finalize().unwrap();
    }

    #[test]
    fn every_scan_is_read_with_its_pose_and_non_finite_points_are_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("scan.E57");
        write_two_scans(&path);
        let read = read_cloud(&path).unwrap();
        assert_eq!(read.vertices_in_file, 4);
        assert_eq!(read.skipped_non_finite, 1);
        let p = &read.cloud.points;
        assert_eq!(p.len(), 3);
        assert_eq!(p[0], Point3::new(1.0, 2.0, 3.0));
        assert_eq!(p[1], Point3::new(4.5e5, 5.1e6, 12.0));
        // (1, 0, 0) turned 90° about z → (0, 1, 0), then shifted by (10, 0, 1).
        assert!(
            (p[2] - Point3::new(10.0, 1.0, 1.0)).norm() < 1e-12,
            "{}",
            p[2]
        );
    }

    #[test]
    fn a_file_that_is_not_e57_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("scan.e57");
        std::fs::write(&path, b"ply\nformat ascii 1.0\n").unwrap();
        let e = read(&path).unwrap_err().to_string();
        assert!(e.contains("scan.e57") && e.contains("E57"), "{e}");
        let e = read(&dir.path().join("missing.e57"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.e57") && e.contains("not found"), "{e}");
    }
}
