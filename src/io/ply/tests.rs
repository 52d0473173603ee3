use super::*;
use crate::io::Location;

fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[track_caller]
fn error_of(bytes: &[u8]) -> ReadError {
    parse(Path::new("e.ply"), bytes).unwrap_err()
}

#[test]
fn ascii_with_nan_normals_and_colours() {
    let dir = tempfile::tempdir().unwrap();
    let text = "ply\nformat ascii 1.0\ncomment hi\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3 0 0 1 10 20 30\nnan .5 0 0 0 1 1 1 1\n-1.5 2.25 1E3 1 0 0 255 0 7\n3 0 1 2\n";
    let p = write(dir.path(), "a.ply", text.as_bytes());
    let r = read(&p).unwrap();
    assert_eq!(r.vertices_in_file, 3);
    assert_eq!(r.skipped_non_finite, 1);
    assert_eq!(
        r.cloud.points,
        vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-1.5, 2.25, 1000.0)]
    );
    assert_eq!(r.cloud.colors, Some(vec![[10, 20, 30], [255, 0, 7]]));
    assert_eq!(r.cloud.normals.unwrap()[1], Vector3::new(1.0, 0.0, 0.0));
    assert_eq!(r.cloud.intensity, None);
}

/// Builds a binary PLY by hand (independently of the writer).
fn binary(big_endian: bool, n: usize, truncate: usize) -> Vec<u8> {
    let fmt = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut b = format!("ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty double x\nproperty double y\nproperty double z\nproperty float intensity\nend_header\n").into_bytes();
    for k in 0..n {
        for v in [k as f64, -(k as f64), 0.5] {
            b.extend(if big_endian {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            });
        }
        let i = k as f32 * 2.0;
        b.extend(if big_endian {
            i.to_be_bytes()
        } else {
            i.to_le_bytes()
        });
    }
    b.truncate(b.len() - truncate);
    b
}

#[test]
fn binary_both_endians_doubles_and_intensity() {
    let dir = tempfile::tempdir().unwrap();
    for big in [false, true] {
        let p = write(dir.path(), "b.ply", &binary(big, 4, 0));
        let r = read(&p).unwrap();
        assert_eq!(r.cloud.len(), 4);
        assert_eq!(r.cloud.points[3], Point3::new(3.0, -3.0, 0.5));
        assert_eq!(r.cloud.intensity.as_ref().unwrap()[2], 4.0);
    }
}

#[test]
fn binary_lists_and_small_types_are_read_past() {
    // A vertex with a list (no fixed record size) between its coordinates, then faces.
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty short x\nproperty list uchar ushort l\nproperty char y\nproperty uint z\nproperty ushort red\nproperty float green\nproperty uchar blue\nelement face 1\nproperty list uint int vertex_indices\nend_header\n".to_vec();
    for (x, l, y, z) in [(-300i16, vec![7u16, 8], -5i8, 70_000u32), (2, vec![], 1, 3)] {
        b.extend(x.to_be_bytes());
        b.push(l.len() as u8);
        for v in l {
            b.extend(v.to_be_bytes());
        }
        b.push(y as u8);
        b.extend(z.to_be_bytes());
        b.extend(0x8000u16.to_be_bytes());
        b.extend(0.5f32.to_be_bytes());
        b.push(9);
    }
    b.extend(3u32.to_be_bytes());
    for i in [0i32, 1, 1] {
        b.extend(i.to_be_bytes());
    }
    let r = parse(Path::new("l.ply"), &b).unwrap();
    assert_eq!(
        r.cloud.points,
        vec![
            Point3::new(-300.0, -5.0, 70_000.0),
            Point3::new(2.0, 1.0, 3.0)
        ]
    );
    assert_eq!(r.cloud.colors, Some(vec![[128, 128, 9], [128, 128, 9]]));
}

#[test]
fn truncated_file_says_how_far_it_got() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "t.ply", &binary(false, 10, 20));
    let e = read(&p).unwrap_err().to_string();
    assert!(
        e.contains("t.ply") && e.contains("ends after 9 of 10 `vertex` elements"),
        "{e}"
    );
    let p = write(dir.path(), "t2.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n");
    let e = read(&p).unwrap_err().to_string();
    assert!(e.contains("ends after 1 of 3 `vertex` elements"), "{e}");
    // A list whose items run past the end: the byte where the element starts to fail.
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty list uchar float l\nend_header\n".to_vec();
    let body = b.len() as u64;
    b.extend([0u8; 12]);
    b.push(200);
    let e = error_of(&b);
    assert_eq!(e.location, Some(Location::Byte(body + 13)), "{e}");
    assert!(e.to_string().contains("ends after 0 of 1 `vertex`"), "{e}");
}

#[test]
fn header_without_xyz_or_not_ply_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "noz.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n");
    let e = read(&p).unwrap_err().to_string();
    assert!(
        e.contains("noz.ply") && e.contains("no `z` property"),
        "{e}"
    );
    let p = write(dir.path(), "x.ply", b"\x89PNG\r\n\x1a\n garbage");
    let e = read(&p).unwrap_err().to_string();
    assert!(e.contains("not a PLY file"), "{e}");
    let p = write(
        dir.path(),
        "h.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
    );
    assert!(read(&p).is_err());
    let e = read(Path::new("/nonexistent.ply")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent.ply: not found"), "{e}");
    let e = read(dir.path()).unwrap_err().to_string();
    assert!(e.ends_with("is a directory, expected a file"), "{e}");
}

#[test]
fn write_then_read_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = PointCloud {
        points: vec![
            Point3::new(512_345.123_456_789, 5_678_901.5, 1e-9),
            Point3::new(-1.0, 0.0, 2.0),
        ],
        normals: Some(vec![
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(1.0, 0.0, 0.0),
        ]),
        colors: Some(vec![[1, 2, 3], [250, 251, 252]]),
        intensity: Some(vec![0.25, 7.0]),
    };
    let p = dir.path().join("w.ply");
    write_binary(&p, &cloud).unwrap();
    let back = read(&p).unwrap();
    assert_eq!(back.cloud, cloud);
    let points = read_points(&p).unwrap();
    assert_eq!(points.cloud, PointCloud::from_points(cloud.points.clone()));
    let bytes = std::fs::read(&p).unwrap();
    let header = b"ply\nformat binary_little_endian 1.0\ncomment written by pipemeasure\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nproperty float intensity\nend_header\n";
    assert!(bytes.starts_with(header));
    assert_eq!(bytes.len(), header.len() + 2 * (24 + 12 + 3 + 4));
}

/// The ply-rs crate panicked (unwrap of a ParseIntError) on header integers beyond u64.
#[test]
fn ply_header_integer_beyond_u64_is_an_error() {
    let e = error_of(b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\nproperty float x\nend_header\n");
    assert_eq!(e.location, Some(Location::Line(3)));
    assert!(e.to_string().contains("field element count"), "{e}");
    let e = error_of(b"ply\nformat ascii 99999999999999999999.0\nend_header\n");
    assert_eq!(e.location, Some(Location::Line(2)));
    assert!(e.to_string().contains("field format version"), "{e}");
}

/// A binary element with no property and a count of 10¹² spun for hours (a 263-byte
/// file), before or after `vertex`.
#[test]
fn ply_element_without_properties_is_refused_at_once() {
    for (before, after) in [
        ("element junk 1000000000000\n", ""),
        ("", "element junk 1000000000000\n"),
    ] {
        let text = format!(
            "ply\nformat binary_little_endian 1.0\n{before}element vertex 1\nproperty float x\nproperty float y\nproperty float z\n{after}end_header\n"
        );
        let mut b = text.into_bytes();
        b.extend([0u8; 12]);
        let e = error_of(&b);
        assert!(
            e.to_string()
                .contains("element `junk` declares 1000000000000 instances but no property"),
            "{e}"
        );
        assert_eq!(
            e.location,
            Some(Location::Line(if before.is_empty() { 7 } else { 3 }))
        );
    }
    // Count 0 without properties is what PCL writes (`element face 0`): fine.
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nend_header\n".to_vec();
    b.extend([0u8; 12]);
    assert_eq!(parse(Path::new("ok.ply"), &b).unwrap().cloud.len(), 1);
}

/// Counts the file cannot hold are refused before anything is allocated or looped.
#[test]
fn ply_lying_counts_are_checked_against_the_file_length() {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 18446744073709551615\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    b.extend([0u8; 24]);
    let e = error_of(&b);
    assert_eq!(e.location, Some(Location::Line(3)));
    assert!(
        e.to_string()
            .contains("ends after 2 of 4000000000 `vertex` elements"),
        "{e}"
    );
}

/// A duplicated property (`x y z x`) was misread without error (ascii rotated the
/// coordinates, binary used a 12-byte stride for 16-byte records).
#[test]
fn ply_duplicated_property_is_an_error() {
    for format in ["ascii", "binary_little_endian"] {
        let text = format!(
            "ply\nformat {format} 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty float x\nend_header\n"
        );
        let mut b = text.into_bytes();
        b.extend(if format == "ascii" {
            b"1 2 3 4\n".to_vec()
        } else {
            vec![0u8; 16]
        });
        let e = error_of(&b);
        assert_eq!(e.location, Some(Location::Line(7)), "{e}");
        assert!(
            e.to_string()
                .contains("property `x` of element `vertex` declared a second time"),
            "{e}"
        );
    }
}

/// An element declared twice replaced the first.
#[test]
fn ply_element_declared_twice_is_an_error() {
    let e = error_of(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5 6\n7 8 9\n");
    assert_eq!(e.location, Some(Location::Line(7)));
    assert!(
        e.to_string()
            .contains("element `vertex` declared a second time (first on line 3)"),
        "{e}"
    );
}

/// Extra values on an ascii row were ignored.
#[test]
fn ply_extra_values_on_an_ascii_row_are_an_error() {
    let e = error_of(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5 6 7\n");
    assert_eq!(e.location, Some(Location::Line(9)));
    assert!(
        e.to_string()
            .contains("1 values after the last property `z` of element `vertex`"),
        "{e}"
    );
}

/// Bytes after the last element were ignored.
#[test]
fn ply_bytes_after_the_last_element_are_an_error() {
    let mut b = binary(false, 2, 0);
    let end = b.len() as u64;
    b.extend(b"trailing");
    let e = error_of(&b);
    assert_eq!(e.location, Some(Location::Byte(end)));
    assert!(
        e.to_string().contains("8 bytes after the last element"),
        "{e}"
    );
    let e = error_of(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n\n4 5 6\n");
    assert_eq!(e.location, Some(Location::Line(10)));
    assert!(e.to_string().contains("text after the last element"), "{e}");
    // Blank lines at the end of an ascii file are not data.
    parse(Path::new("ok.ply"), b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n\n  \n").unwrap();
}

/// Binary errors gave a fake line number and no byte offset.
#[test]
fn ply_binary_errors_name_the_byte() {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty list char float l\nend_header\n".to_vec();
    let body = b.len() as u64;
    b.extend([0u8; 12]);
    b.push(0);
    b.extend([0u8; 12]);
    b.push(0xff); // length -1
    let e = error_of(&b);
    assert_eq!(e.location, Some(Location::Byte(body + 25)), "{e}");
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!("e.ply (byte {})", body + 25)),
        "{msg}"
    );
    assert!(
        msg.contains(&format!("`vertex` element 1 (from byte {})", body + 13)),
        "{msg}"
    );
    assert!(msg.contains("list `l` has length -1"), "{msg}");
}

/// A non-UTF-8 byte in a header comment gave "not a PLY file".
#[test]
fn ply_non_utf8_header_comment_is_read() {
    let r = parse(Path::new("c.ply"), b"ply\nformat ascii 1.0\ncomment scanned by \xe9quipe \xff\nobj_info \xfe\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n").unwrap();
    assert_eq!(r.cloud.points, vec![Point3::new(1.0, 2.0, 3.0)]);
}

#[test]
fn ascii_values_must_fit_their_type() {
    let e = error_of(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n1 2 3 256 0 0\n");
    assert_eq!(e.location, Some(Location::Line(11)));
    assert!(
        e.to_string()
            .contains("value \"256\" of `red` is not a valid uchar"),
        "{e}"
    );
}

#[test]
fn streamed_in_chunks_gives_the_points_in_order_and_the_same_errors() {
    let dir = tempfile::tempdir().unwrap();
    for big in [false, true] {
        // 10 points (k, −k, 0.5), in chunks of 3: 3 + 3 + 3 + 1.
        let p = write(dir.path(), "s.ply", &binary(big, 10, 0));
        let mut chunks: Vec<Vec<Point3<f64>>> = Vec::new();
        let summary = stream_points(&p, 3, &mut |c| chunks.push(c.to_vec())).unwrap();
        assert_eq!(summary.vertices_in_file, 10);
        assert_eq!(summary.skipped_non_finite, 0);
        assert_eq!(
            chunks.iter().map(Vec::len).collect::<Vec<_>>(),
            vec![3, 3, 3, 1]
        );
        let expected: Vec<Point3<f64>> = (0..10)
            .map(|k| Point3::new(k as f64, -(k as f64), 0.5))
            .collect();
        assert_eq!(chunks.concat(), expected);
        // A truncated body: the same error as reading it whole, naming file and byte.
        let p = write(dir.path(), "t.ply", &binary(big, 10, 5));
        let whole = read_points(&p).unwrap_err().to_string();
        let streamed = stream_points(&p, 3, &mut |_| {}).unwrap_err().to_string();
        assert_eq!(whole, streamed);
        assert!(streamed.contains("t.ply"), "{streamed}");
    }
    // The ascii file with a NaN point: skipped and counted, as by `read`.
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\nnan 0 0\n4 5 6\n";
    let mut points = Vec::new();
    let summary = parse_streamed(Path::new("a.ply"), text.as_bytes(), 1, &mut |c| {
        points.extend_from_slice(c)
    })
    .unwrap();
    assert_eq!(
        (summary.vertices_in_file, summary.skipped_non_finite),
        (3, 1)
    );
    assert_eq!(
        points,
        vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
    );
    let e = vertex_count(Path::new("missing.ply"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.ply"), "{e}");
}
