//! The e57 crate's real test files (`../shared/data/e57_testdata`): the same bunny
//! in every encoding reads to the same points, in one piece or streamed in chunks, and the
//! corrupt files are clear errors naming the file, never a panic.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};

use nalgebra::Point3;
use pipemeasure::io::e57::{declared_points, read, stream};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/e57_testdata")
        .join(name)
}

fn streamed(path: &Path, chunk: usize) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    stream(path, chunk, &mut |c| out.extend_from_slice(c)).unwrap();
    out
}

const BUNNY_POINTS: usize = 30_571;

#[test]
fn the_bunny_reads_to_the_same_points_from_every_encoding() {
    let reference = read(&data("bunnyDouble.e57")).unwrap();
    assert_eq!(reference.cloud.len(), BUNNY_POINTS);
    assert_eq!(reference.skipped_non_finite, 0);
    // The integer encodings hold the double file's values exactly (they were made from
    // the same grid); single precision within half a unit in the last place.
    for name in [
        "bunnyInt19.e57",
        "bunnyInt21.e57",
        "bunnyInt24.e57",
        "bunnyInt32.e57",
        "bunnyFloat.e57",
    ] {
        let path = data(name);
        assert_eq!(
            declared_points(&path).unwrap(),
            BUNNY_POINTS as u64,
            "{name}"
        );
        let r = read(&path).unwrap();
        assert_eq!(r.vertices_in_file, BUNNY_POINTS, "{name}");
        assert_eq!(r.cloud.len(), BUNNY_POINTS, "{name}");
        for (p, q) in r.cloud.points.iter().zip(&reference.cloud.points) {
            for k in 0..3 {
                let tolerance = if name == "bunnyFloat.e57" {
                    q[k].abs() * f64::from(f32::EPSILON) / 2.0
                } else {
                    0.0
                };
                assert!((p[k] - q[k]).abs() <= tolerance, "{name}: {p} against {q}");
            }
        }
        // Streamed in chunks of 1000: the same points in the same order.
        assert_eq!(streamed(&path, 1000), r.cloud.points, "{name}");
    }
}

#[test]
fn a_corrupt_e57_is_a_clear_error_naming_the_file() {
    let path = data("corrupt_crc.e57");
    for e in [
        read(&path).unwrap_err().to_string(),
        stream(&path, 1000, &mut |_| {}).unwrap_err().to_string(),
        declared_points(&path).unwrap_err().to_string(),
    ] {
        assert!(
            e.contains("corrupt_crc.e57") && e.contains("checksum"),
            "{e}"
        );
    }
}

#[test]
fn invalid_cartesian_points_are_skipped_and_counted() {
    // The crate's file of three points, two flagged invalid.
    let r = read(&data("cartesian_invalid_state_single.e57")).unwrap();
    assert_eq!(
        (r.vertices_in_file, r.skipped_non_finite, r.cloud.len()),
        (3, 2, 1)
    );
}
