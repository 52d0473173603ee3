//! COLMAP's text model format (`cameras.txt`, `images.txt`, `points3D.txt`).

use std::io::Write;
use std::path::Path;

use nalgebra::Vector2;

use super::{
    CameraId, ColmapCamera, ColmapModel, Image, ImageId, ImagesRead, Locations, ModelFormat,
    Point2D, Point3D, Point3dId, Reconstruction, TrackElement, camera_problem,
};
use crate::io::Location;
use crate::io::atomic::write_atomic;
use crate::io::error::{ReadError, ReadErrorKind, WriteError};

/// A text file being parsed: path and the current 1-based line, for errors.
struct Cursor<'a> {
    path: &'a Path,
    line: usize,
}

impl Cursor<'_> {
    fn err(&self, kind: ReadErrorKind) -> ReadError {
        ReadError::at_line(self.path, self.line, kind)
    }

    fn parse<T: std::str::FromStr>(
        &self,
        value: Option<&str>,
        field: &'static str,
        expected: &'static str,
    ) -> Result<T, ReadError> {
        let Some(value) = value else {
            return Err(self.err(ReadErrorKind::Truncated(format!(
                "line ends before {field}"
            ))));
        };
        value.parse().map_err(|_| {
            self.err(ReadErrorKind::Field {
                field,
                value: value.to_string(),
                expected,
            })
        })
    }

    fn parse_f64(&self, value: Option<&str>, field: &'static str) -> Result<f64, ReadError> {
        let v: f64 = self.parse(value, field, "a number")?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(ReadErrorKind::Field {
                field,
                value: value.unwrap_or_default().to_string(),
                expected: "a finite number",
            }))
        }
    }
}

/// The text of a file's bytes (`path` names it in errors).
fn text_of<'a>(path: &Path, bytes: &'a [u8]) -> Result<&'a str, ReadError> {
    std::str::from_utf8(bytes).map_err(|e| {
        let line = 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        ReadError::at_line(
            path,
            line,
            ReadErrorKind::Invalid("the file is not UTF-8 text".into()),
        )
    })
}

/// Whether a line carries data (not blank, not a comment).
fn is_data(line: &str) -> bool {
    let t = line.trim();
    !t.is_empty() && !t.starts_with('#')
}

/// The format this module reads.
const FORMAT: ModelFormat = ModelFormat::Text;

/// Parses the three files' bytes (cameras, images, points); `dir` names them in errors.
pub(super) fn parse(
    dir: &Path,
    [cameras, images, points]: [&[u8]; 3],
) -> Result<(Reconstruction, Locations), ReadError> {
    let [c, i, p] = FORMAT.files().map(|f| dir.join(f));
    let cameras = read_cameras(&c, cameras)?;
    let images = read_images(&i, images)?;
    let (points3d, points) = read_points(&p, points)?;
    Ok((
        Reconstruction {
            cameras,
            images: images.images,
            points3d,
        },
        Locations {
            images: images.locations,
            points,
        },
    ))
}

fn read_cameras(
    path: &Path,
    bytes: &[u8],
) -> Result<std::collections::BTreeMap<CameraId, ColmapCamera>, ReadError> {
    let text = text_of(path, bytes)?;
    let mut cameras = std::collections::BTreeMap::new();
    for (k, line) in text.lines().enumerate() {
        let cur = Cursor { path, line: k + 1 };
        if !is_data(line) {
            continue;
        }
        let mut f = line.split_whitespace();
        let id = CameraId(cur.parse(f.next(), "CAMERA_ID", "an unsigned 32-bit integer")?);
        let name = f.next().unwrap_or_default();
        let model = ColmapModel::from_name(name).ok_or_else(|| {
            cur.err(ReadErrorKind::Field {
                field: "MODEL",
                value: name.to_string(),
                expected: "a COLMAP camera model name",
            })
        })?;
        let width = cur.parse(f.next(), "WIDTH", "an unsigned integer")?;
        let height = cur.parse(f.next(), "HEIGHT", "an unsigned integer")?;
        let params: Vec<f64> = f
            .map(|v| cur.parse_f64(Some(v), "PARAMS"))
            .collect::<Result<_, _>>()?;
        if params.len() != model.num_params() {
            return Err(cur.err(ReadErrorKind::FieldCount {
                expected: format!("{} parameters for {}", model.num_params(), model.name()),
                found: params.len(),
            }));
        }
        let camera = ColmapCamera {
            model,
            width,
            height,
            params,
        };
        if let Some((field, value, expected)) = camera_problem(&camera) {
            return Err(cur.err(ReadErrorKind::Field {
                field,
                value,
                expected,
            }));
        }
        if cameras.insert(id, camera).is_some() {
            return Err(cur.err(ReadErrorKind::Invalid(format!(
                "camera {} defined twice",
                id.0
            ))));
        }
    }
    Ok(cameras)
}

pub(super) fn read_images(path: &Path, bytes: &[u8]) -> Result<ImagesRead, ReadError> {
    let mut order = Vec::new();
    let mut locations = std::collections::BTreeMap::new();
    let text = text_of(path, bytes)?;
    let mut images = std::collections::BTreeMap::new();
    let mut lines = text.lines().enumerate();
    while let Some((k, line)) = lines.next() {
        let cur = Cursor { path, line: k + 1 };
        if !is_data(line) {
            continue;
        }
        let mut f = line.split_whitespace();
        let id = ImageId(cur.parse(f.next(), "IMAGE_ID", "an unsigned 32-bit integer")?);
        let mut qvec = [0.0; 4];
        for (q, field) in qvec.iter_mut().zip(["QW", "QX", "QY", "QZ"]) {
            *q = cur.parse_f64(f.next(), field)?;
        }
        let mut tvec = [0.0; 3];
        for (t, field) in tvec.iter_mut().zip(["TX", "TY", "TZ"]) {
            *t = cur.parse_f64(f.next(), field)?;
        }
        let camera_id = CameraId(cur.parse(f.next(), "CAMERA_ID", "an unsigned 32-bit integer")?);
        // The name is the rest of the line (COLMAP itself stops at the first space).
        let rest: Vec<&str> = f.collect();
        if rest.is_empty() {
            return Err(cur.err(ReadErrorKind::Truncated("line ends before NAME".into())));
        }
        let name = rest.join(" ");
        if qvec.iter().map(|q| q * q).sum::<f64>() < 1e-12 {
            return Err(cur.err(ReadErrorKind::Invalid(format!(
                "image {} has a zero quaternion",
                id.0
            ))));
        }
        // The next line holds the 2D points, and may be empty, but it must be there: COLMAP
        // writes it for every image.
        let Some((k2, points_line)) = lines.next() else {
            return Err(cur.err(ReadErrorKind::Truncated(format!(
                "the file ends before the POINTS2D line of image {} (each image takes two lines; the second may be empty)",
                id.0
            ))));
        };
        let cur = Cursor { path, line: k2 + 1 };
        let fields: Vec<&str> = points_line.split_whitespace().collect();
        if !fields.len().is_multiple_of(3) {
            return Err(cur.err(ReadErrorKind::FieldCount {
                expected: "a multiple of 3 (X, Y, POINT3D_ID)".into(),
                found: fields.len(),
            }));
        }
        let mut points2d = Vec::with_capacity(fields.len() / 3);
        for p in fields.chunks_exact(3) {
            let x = cur.parse_f64(Some(p[0]), "X")?;
            let y = cur.parse_f64(Some(p[1]), "Y")?;
            let pid: i64 = cur.parse(Some(p[2]), "POINT3D_ID", "an integer (-1 for none)")?;
            let point3d_id = match pid {
                -1 => None,
                v if v >= 0 => Some(Point3dId(v as u64)),
                _ => {
                    return Err(cur.err(ReadErrorKind::Field {
                        field: "POINT3D_ID",
                        value: p[2].to_string(),
                        expected: "a non-negative integer or -1",
                    }));
                }
            };
            points2d.push(Point2D {
                uv: Vector2::new(x, y),
                point3d_id,
            });
        }
        let image = Image {
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        };
        order.push(id);
        locations.insert(id, (Location::Line(k + 1), Location::Line(k2 + 1)));
        if images.insert(id, image).is_some() {
            return Err(
                Cursor { path, line: k + 1 }.err(ReadErrorKind::Invalid(format!(
                    "image {} defined twice",
                    id.0
                ))),
            );
        }
    }
    Ok(ImagesRead {
        images,
        order,
        locations,
    })
}

/// Points by id, and the line of each.
type PointsRead = (
    std::collections::BTreeMap<Point3dId, Point3D>,
    std::collections::BTreeMap<Point3dId, Location>,
);

fn read_points(path: &Path, bytes: &[u8]) -> Result<PointsRead, ReadError> {
    let text = text_of(path, bytes)?;
    let mut points = std::collections::BTreeMap::new();
    let mut lines_of = std::collections::BTreeMap::new();
    for (k, line) in text.lines().enumerate() {
        let cur = Cursor { path, line: k + 1 };
        if !is_data(line) {
            continue;
        }
        let mut f = line.split_whitespace();
        let id = Point3dId(cur.parse(f.next(), "POINT3D_ID", "an unsigned integer")?);
        let mut xyz = [0.0; 3];
        for (v, field) in xyz.iter_mut().zip(["X", "Y", "Z"]) {
            *v = cur.parse_f64(f.next(), field)?;
        }
        let mut rgb = [0u8; 3];
        for (v, field) in rgb.iter_mut().zip(["R", "G", "B"]) {
            *v = cur.parse(f.next(), field, "an integer 0-255")?;
        }
        let error = cur.parse_f64(f.next(), "ERROR")?;
        let rest: Vec<&str> = f.collect();
        if !rest.len().is_multiple_of(2) {
            return Err(cur.err(ReadErrorKind::FieldCount {
                expected: "pairs (IMAGE_ID, POINT2D_IDX) after ERROR".into(),
                found: rest.len(),
            }));
        }
        let mut track = Vec::with_capacity(rest.len() / 2);
        for pair in rest.chunks_exact(2) {
            track.push(TrackElement {
                image_id: ImageId(cur.parse(
                    Some(pair[0]),
                    "IMAGE_ID",
                    "an unsigned 32-bit integer",
                )?),
                point2d_idx: cur.parse(
                    Some(pair[1]),
                    "POINT2D_IDX",
                    "an unsigned 32-bit integer",
                )?,
            });
        }
        if points
            .insert(
                id,
                Point3D {
                    xyz,
                    rgb,
                    error,
                    track,
                },
            )
            .is_some()
        {
            return Err(cur.err(ReadErrorKind::Invalid(format!(
                "point {} defined twice",
                id.0
            ))));
        }
        lines_of.insert(id, Location::Line(k + 1));
    }
    Ok((points, lines_of))
}

/// Writes `cameras.txt` alone (e.g. beside undistorted frames).
pub(super) fn write_cameras(
    path: &Path,
    cameras: &std::collections::BTreeMap<CameraId, ColmapCamera>,
) -> Result<(), WriteError> {
    write_atomic(path, |w| {
        writeln!(w, "# Camera list with one line of data per camera:")?;
        writeln!(w, "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]")?;
        writeln!(w, "# Number of cameras: {}", cameras.len())?;
        for (id, cam) in cameras {
            writeln!(w, "{}", camera_line(*id, cam))?;
        }
        Ok(())
    })
}

/// One `cameras.txt` data line.
pub(super) fn camera_line(id: CameraId, cam: &ColmapCamera) -> String {
    let mut line = format!("{} {} {} {}", id.0, cam.model.name(), cam.width, cam.height);
    for p in &cam.params {
        line.push_str(&format!(" {p:?}"));
    }
    line
}

pub(super) fn write(model: &Reconstruction, dir: &Path) -> Result<(), WriteError> {
    write_cameras(&dir.join("cameras.txt"), &model.cameras)?;
    write_atomic(&dir.join("images.txt"), |w| {
        let total: usize = model.images.values().map(|i| i.points2d.len()).sum();
        let mean = if model.images.is_empty() {
            0.0
        } else {
            total as f64 / model.images.len() as f64
        };
        writeln!(w, "# Image list with two lines of data per image:")?;
        writeln!(
            w,
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME"
        )?;
        writeln!(w, "#   POINTS2D[] as (X, Y, POINT3D_ID)")?;
        writeln!(
            w,
            "# Number of images: {}, mean observations per image: {mean}",
            model.images.len()
        )?;
        for (id, im) in &model.images {
            let [qw, qx, qy, qz] = im.qvec;
            let [tx, ty, tz] = im.tvec;
            writeln!(
                w,
                "{} {qw:?} {qx:?} {qy:?} {qz:?} {tx:?} {ty:?} {tz:?} {} {}",
                id.0, im.camera_id.0, im.name
            )?;
            let mut first = true;
            for p in &im.points2d {
                if !first {
                    write!(w, " ")?;
                }
                first = false;
                let pid = p.point3d_id.map_or(-1, |p| p.0 as i64);
                write!(w, "{:?} {:?} {pid}", p.uv.x, p.uv.y)?;
            }
            writeln!(w)?;
        }
        Ok(())
    })?;
    write_atomic(&dir.join("points3D.txt"), |w| {
        let total: usize = model.points3d.values().map(|p| p.track.len()).sum();
        let mean = if model.points3d.is_empty() {
            0.0
        } else {
            total as f64 / model.points3d.len() as f64
        };
        writeln!(w, "# 3D point list with one line of data per point:")?;
        writeln!(
            w,
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"
        )?;
        writeln!(
            w,
            "# Number of points: {}, mean track length: {mean}",
            model.points3d.len()
        )?;
        for (id, p) in &model.points3d {
            let [x, y, z] = p.xyz;
            let [r, g, b] = p.rgb;
            write!(w, "{} {x:?} {y:?} {z:?} {r} {g} {b} {:?}", id.0, p.error)?;
            for el in &p.track {
                write!(w, " {} {}", el.image_id.0, el.point2d_idx)?;
            }
            writeln!(w)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_model(files: &[(&str, &str)]) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let defaults = [
            ("cameras.txt", "1 PINHOLE 10 10 5 5 5 5\n"),
            ("images.txt", "# c\n1 1 0 0 0 0 0 0 1 a.png\n\n"),
            ("points3D.txt", ""),
        ];
        for (name, content) in defaults {
            let content = files
                .iter()
                .find(|(n, _)| *n == name)
                .map_or(content, |(_, c)| *c);
            std::fs::write(dir.path().join(name), content).unwrap();
        }
        dir
    }

    #[track_caller]
    fn error_of(files: &[(&str, &str)]) -> String {
        let dir = write_model(files);
        Reconstruction::read(dir.path()).unwrap_err().to_string()
    }

    #[test]
    fn minimal_model_parses() {
        let dir = write_model(&[]);
        let m = Reconstruction::read(dir.path()).unwrap();
        assert_eq!(m.cameras.len(), 1);
        assert_eq!(m.images[&ImageId(1)].points2d.len(), 0);
    }

    #[test]
    fn malformed_files_name_file_and_line() {
        let e = error_of(&[("cameras.txt", "# x\n1 PINHOLE 10 10 5 5 5\n")]);
        assert!(
            e.contains("cameras.txt:2") && e.contains("4 parameters for PINHOLE"),
            "{e}"
        );
        let e = error_of(&[("cameras.txt", "1 PINHOLE 10 10 5 5 5 5\n2 FISH 10 10 1\n")]);
        assert!(e.contains("cameras.txt:2") && e.contains("MODEL"), "{e}");
        let e = error_of(&[("cameras.txt", "x PINHOLE 10 10 5 5 5 5\n")]);
        assert!(
            e.contains("cameras.txt:1") && e.contains("CAMERA_ID"),
            "{e}"
        );
        let e = error_of(&[("images.txt", "1 1 0 0 0 0 0 zero 1 a.png\n\n")]);
        assert!(e.contains("images.txt:1") && e.contains("TZ"), "{e}");
        let e = error_of(&[("images.txt", "1 1 0 0 0 0 0 0 1 a.png\n1.0 2.0\n")]);
        assert!(
            e.contains("images.txt:2") && e.contains("multiple of 3"),
            "{e}"
        );
        let e = error_of(&[("images.txt", "1 1 0 0 0 0 0 0 1\n\n")]);
        assert!(e.contains("images.txt:1") && e.contains("NAME"), "{e}");
        let e = error_of(&[("images.txt", "1 0 0 0 0 0 0 0 1 a.png\n\n")]);
        assert!(
            e.contains("images.txt:1") && e.contains("zero quaternion"),
            "{e}"
        );
        let e = error_of(&[("points3D.txt", "\n\n5 1 2 3 1 2 3 0.5 1\n")]);
        assert!(e.contains("points3D.txt:3") && e.contains("pairs"), "{e}");
        let e = error_of(&[("points3D.txt", "5 1 2 3 300 2 3 0.5\n")]);
        assert!(e.contains("points3D.txt:1") && e.contains("field R"), "{e}");
        let e = error_of(&[("points3D.txt", "5 1 nan 3 3 2 3 0.5\n")]);
        assert!(e.contains("points3D.txt:1") && e.contains("finite"), "{e}");
    }

    /// `images.txt` naming a POINT3D_ID that points3D.txt does not define was
    /// accepted.
    #[test]
    fn a_point3d_id_that_does_not_exist_is_an_error() {
        let e = error_of(&[
            (
                "images.txt",
                "# c\n1 1 0 0 0 0 0 0 1 a.png\n1.5 2.5 -1 3 4 99\n",
            ),
            ("points3D.txt", ""),
        ]);
        assert_eq!(
            e.rsplit('/').next().unwrap(),
            "images.txt:3: field POINT3D_ID of 2D point 1 of image 1 is 99, which points3D.txt does not define"
        );
    }

    /// A missing last POINTS2D line showed up later as a confusing points3D.txt
    /// error.
    #[test]
    fn a_missing_points2d_line_names_the_image() {
        for images in ["1 1 0 0 0 0 0 0 1 a.png\n", "1 1 0 0 0 0 0 0 1 a.png"] {
            let e = error_of(&[
                ("images.txt", images),
                ("points3D.txt", "7 1 2 3 1 2 3 0.5 1 0\n"),
            ]);
            assert!(
                e.contains("images.txt:1: file ends early: the file ends before the POINTS2D line of image 1"),
                "{e}"
            );
        }
    }

    /// A camera 0 or 4.8e12 px wide was blamed on the focal length, without file,
    /// line or field.
    #[test]
    fn camera_size_and_focal_length_name_file_line_and_field() {
        let cases = [
            (
                "1 PINHOLE 0 10 5 5 5 5\n",
                "cameras.txt:1: field WIDTH is \"0\"",
            ),
            (
                "# x\n1 PINHOLE 4800000000000 10 5 5 5 5\n",
                "cameras.txt:2: field WIDTH is \"4800000000000\"",
            ),
            (
                "1 PINHOLE 10 70000 5 5 5 5\n",
                "cameras.txt:1: field HEIGHT is \"70000\"",
            ),
            (
                "1 PINHOLE 20000 20000 5 5 5 5\n",
                "cameras.txt:1: field WIDTH is \"20000 (x 20000 = 400000000 px)\"",
            ),
            (
                "1 SIMPLE_RADIAL 10 10 0 5 5 0.1\n",
                "cameras.txt:1: field PARAMS[0] (f) is \"0\"",
            ),
            (
                "1 OPENCV 10 10 5 -5 5 5 0 0 0 0\n",
                "cameras.txt:1: field PARAMS[1] (fy) is \"-5\"",
            ),
        ];
        for (cameras, want) in cases {
            let e = error_of(&[("cameras.txt", cameras)]);
            assert!(e.contains(want), "{e}\nwanted {want}");
        }
    }
}
