//! COLMAP's binary model format (`cameras.bin`, `images.bin`, `points3D.bin`), little endian,
//! as COLMAP 3.8 `reconstruction.cc` reads and writes it.

use std::collections::BTreeMap;
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

/// COLMAP's `kInvalidPoint3DId` (u64::MAX) marks an untriangulated 2D point.
const INVALID_POINT3D: u64 = u64::MAX;

/// A byte buffer being decoded, with the file path for errors.
struct Reader<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], ReadError> {
        if self.data.len() - self.pos < n {
            return Err(ReadError::at_byte(
                self.path,
                self.pos as u64,
                ReadErrorKind::Truncated(format!(
                    "{what} needs {n} bytes, {} left",
                    self.data.len() - self.pos
                )),
            ));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u8(&mut self, what: &str) -> Result<u8, ReadError> {
        Ok(self.take(1, what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32, ReadError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn i32(&mut self, what: &str) -> Result<i32, ReadError> {
        Ok(self.u32(what)? as i32)
    }

    fn u64(&mut self, what: &str) -> Result<u64, ReadError> {
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }

    fn f64(&mut self, what: &str) -> Result<f64, ReadError> {
        let at = self.pos;
        let v = f64::from_bits(self.u64(what)?);
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.invalid_at(at, format!("{what} is not finite ({v})")))
        }
    }

    /// A count that must be satisfiable by the remaining bytes (`min_bytes` per item), so that a
    /// corrupt count cannot trigger a huge allocation.
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize, ReadError> {
        let at = self.pos;
        let n = self.u64(what)?;
        let left = (self.data.len() - self.pos) as u64;
        if n.saturating_mul(min_bytes as u64) > left {
            return Err(ReadError::at_byte(
                self.path,
                at as u64,
                ReadErrorKind::Truncated(format!("{what} is {n} but only {left} bytes follow")),
            ));
        }
        Ok(n as usize)
    }

    fn invalid_at(&self, at: usize, message: String) -> ReadError {
        ReadError::at_byte(self.path, at as u64, ReadErrorKind::Invalid(message))
    }
}

/// The format this module reads.
const FORMAT: ModelFormat = ModelFormat::Binary;

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

fn read_cameras(path: &Path, data: &[u8]) -> Result<BTreeMap<CameraId, ColmapCamera>, ReadError> {
    let mut r = Reader { path, data, pos: 0 };
    let n = r.count("number of cameras", 24)?;
    let mut cameras = BTreeMap::new();
    for _ in 0..n {
        let at = r.pos;
        let id = CameraId(r.u32("camera id")?);
        let model_id = r.i32("model id")?;
        let model = ColmapModel::from_id(model_id)
            .ok_or_else(|| r.invalid_at(at + 4, format!("unknown camera model id {model_id}")))?;
        let width = r.u64("width")?;
        let height = r.u64("height")?;
        let params = (0..model.num_params())
            .map(|_| r.f64("camera parameter"))
            .collect::<Result<_, _>>()?;
        let camera = ColmapCamera {
            model,
            width,
            height,
            params,
        };
        if let Some((field, value, expected)) = camera_problem(&camera) {
            // The width follows the id and the model id; the parameters the height.
            let field_at = match field {
                "WIDTH" => at + 8,
                "HEIGHT" => at + 16,
                _ if field.starts_with("PARAMS[1]") => at + 32,
                _ => at + 24,
            };
            return Err(ReadError::at_byte(
                path,
                field_at as u64,
                ReadErrorKind::Field {
                    field,
                    value,
                    expected,
                },
            ));
        }
        if cameras.insert(id, camera).is_some() {
            return Err(r.invalid_at(at, format!("camera {} defined twice", id.0)));
        }
    }
    trailing(&r)?;
    Ok(cameras)
}

pub(super) fn read_images(path: &Path, data: &[u8]) -> Result<ImagesRead, ReadError> {
    let mut order = Vec::new();
    let mut locations = BTreeMap::new();
    let mut r = Reader { path, data, pos: 0 };
    let n = r.count("number of images", 73)?;
    let mut images = BTreeMap::new();
    for _ in 0..n {
        let at = r.pos;
        let id = ImageId(r.u32("image id")?);
        let mut qvec = [0.0; 4];
        for q in &mut qvec {
            *q = r.f64("quaternion")?;
        }
        let mut tvec = [0.0; 3];
        for t in &mut tvec {
            *t = r.f64("translation")?;
        }
        let camera_id = CameraId(r.u32("camera id")?);
        let name_at = r.pos;
        let rest = &r.data[r.pos..];
        let Some(end) = rest.iter().position(|&b| b == 0) else {
            return Err(ReadError::at_byte(
                path,
                name_at as u64,
                ReadErrorKind::Truncated("image name has no terminating NUL".into()),
            ));
        };
        let name = String::from_utf8(rest[..end].to_vec())
            .map_err(|_| r.invalid_at(name_at, "image name is not UTF-8".into()))?;
        r.pos += end + 1;
        if qvec.iter().map(|q| q * q).sum::<f64>() < 1e-12 {
            return Err(r.invalid_at(at, format!("image {} has a zero quaternion", id.0)));
        }
        let points_at = r.pos;
        let np = r.count("number of 2D points", 24)?;
        let mut points2d = Vec::with_capacity(np);
        for _ in 0..np {
            let x = r.f64("2D point x")?;
            let y = r.f64("2D point y")?;
            let pid = r.u64("3D point id")?;
            let point3d_id = (pid != INVALID_POINT3D).then_some(Point3dId(pid));
            points2d.push(Point2D {
                uv: Vector2::new(x, y),
                point3d_id,
            });
        }
        order.push(id);
        locations.insert(
            id,
            (Location::Byte(at as u64), Location::Byte(points_at as u64)),
        );
        if images
            .insert(
                id,
                Image {
                    qvec,
                    tvec,
                    camera_id,
                    name,
                    points2d,
                },
            )
            .is_some()
        {
            return Err(r.invalid_at(at, format!("image {} defined twice", id.0)));
        }
    }
    trailing(&r)?;
    Ok(ImagesRead {
        images,
        order,
        locations,
    })
}

/// Points by id, and the byte of each record.
type PointsRead = (BTreeMap<Point3dId, Point3D>, BTreeMap<Point3dId, Location>);

fn read_points(path: &Path, data: &[u8]) -> Result<PointsRead, ReadError> {
    let mut r = Reader { path, data, pos: 0 };
    let n = r.count("number of points", 43)?;
    let mut points = BTreeMap::new();
    let mut records = BTreeMap::new();
    for _ in 0..n {
        let at = r.pos;
        let id = Point3dId(r.u64("point id")?);
        let mut xyz = [0.0; 3];
        for v in &mut xyz {
            *v = r.f64("point coordinate")?;
        }
        let mut rgb = [0u8; 3];
        for v in &mut rgb {
            *v = r.u8("colour")?;
        }
        let error = r.f64("reprojection error")?;
        let len = r.count("track length", 8)?;
        let mut track = Vec::with_capacity(len);
        for _ in 0..len {
            track.push(TrackElement {
                image_id: ImageId(r.u32("track image id")?),
                point2d_idx: r.u32("track 2D point index")?,
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
            return Err(r.invalid_at(at, format!("point {} defined twice", id.0)));
        }
        records.insert(id, Location::Byte(at as u64));
    }
    trailing(&r)?;
    Ok((points, records))
}

fn trailing(r: &Reader<'_>) -> Result<(), ReadError> {
    if r.pos == r.data.len() {
        Ok(())
    } else {
        Err(r.invalid_at(
            r.pos,
            format!(
                "{} unexpected bytes after the last record",
                r.data.len() - r.pos
            ),
        ))
    }
}

pub(super) fn write(model: &Reconstruction, dir: &Path) -> Result<(), WriteError> {
    write_atomic(&dir.join("cameras.bin"), |w| {
        w.write_all(&(model.cameras.len() as u64).to_le_bytes())?;
        for (id, cam) in &model.cameras {
            w.write_all(&id.0.to_le_bytes())?;
            w.write_all(&cam.model.id().to_le_bytes())?;
            w.write_all(&cam.width.to_le_bytes())?;
            w.write_all(&cam.height.to_le_bytes())?;
            for p in &cam.params {
                w.write_all(&p.to_le_bytes())?;
            }
        }
        Ok(())
    })?;
    write_atomic(&dir.join("images.bin"), |w| {
        w.write_all(&(model.images.len() as u64).to_le_bytes())?;
        for (id, im) in &model.images {
            w.write_all(&id.0.to_le_bytes())?;
            for v in im.qvec.iter().chain(&im.tvec) {
                w.write_all(&v.to_le_bytes())?;
            }
            w.write_all(&im.camera_id.0.to_le_bytes())?;
            w.write_all(im.name.as_bytes())?;
            w.write_all(&[0])?;
            w.write_all(&(im.points2d.len() as u64).to_le_bytes())?;
            for p in &im.points2d {
                w.write_all(&p.uv.x.to_le_bytes())?;
                w.write_all(&p.uv.y.to_le_bytes())?;
                w.write_all(&p.point3d_id.map_or(INVALID_POINT3D, |p| p.0).to_le_bytes())?;
            }
        }
        Ok(())
    })?;
    write_atomic(&dir.join("points3D.bin"), |w| {
        w.write_all(&(model.points3d.len() as u64).to_le_bytes())?;
        for (id, p) in &model.points3d {
            w.write_all(&id.0.to_le_bytes())?;
            for v in &p.xyz {
                w.write_all(&v.to_le_bytes())?;
            }
            w.write_all(&p.rgb)?;
            w.write_all(&p.error.to_le_bytes())?;
            w.write_all(&(p.track.len() as u64).to_le_bytes())?;
            for el in &p.track {
                w.write_all(&el.image_id.0.to_le_bytes())?;
                w.write_all(&el.point2d_idx.to_le_bytes())?;
            }
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::colmap::ModelFormat;

    #[test]
    fn truncated_and_corrupt_files_name_the_byte() {
        let dir = tempfile::tempdir().unwrap();
        crate::io::colmap::tests::sample()
            .write(dir.path(), ModelFormat::Binary)
            .unwrap();
        let images = dir.path().join("images.bin");
        let bytes = std::fs::read(&images).unwrap();
        std::fs::write(&images, &bytes[..bytes.len() - 5]).unwrap();
        let e = Reconstruction::read(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("images.bin (byte") && e.contains("ends early"),
            "{e}"
        );

        // A huge point count must not allocate: it is reported against the bytes left.
        let mut bad = bytes.clone();
        bad[..8].copy_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&images, &bad).unwrap();
        let e = Reconstruction::read(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("images.bin (byte 0)") && e.contains("number of images"),
            "{e}"
        );

        std::fs::write(&images, &bytes).unwrap();
        let cameras = dir.path().join("cameras.bin");
        let mut cam = std::fs::read(&cameras).unwrap();
        cam[12..16].copy_from_slice(&42i32.to_le_bytes());
        std::fs::write(&cameras, &cam).unwrap();
        let e = Reconstruction::read(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("cameras.bin (byte 12)") && e.contains("model id 42"),
            "{e}"
        );
    }

    /// Binary side: a camera 4.8e12 px wide, and a 2D point observing a 3D point
    /// that does not exist, name the byte and the field.
    #[test]
    fn camera_width_and_missing_point3d_name_the_byte() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = crate::io::colmap::tests::sample();
        m.cameras.get_mut(&CameraId(1)).unwrap().width = 4_800_000_000_000;
        m.write(dir.path(), ModelFormat::Binary).unwrap();
        let e = Reconstruction::read(dir.path()).unwrap_err().to_string();
        // Record 1: count (8 bytes), id and model id (8): the width at byte 16.
        assert!(
            e.ends_with("cameras.bin (byte 16): field WIDTH is \"4800000000000\", expected a width from 1 to 65535 px"),
            "{e}"
        );
        let mut m = crate::io::colmap::tests::sample();
        m.images.get_mut(&ImageId(10)).unwrap().points2d[0].point3d_id = Some(Point3dId(77));
        m.write(dir.path(), ModelFormat::Binary).unwrap();
        let e = Reconstruction::read(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("images.bin (byte ")
                && e.contains("field POINT3D_ID of 2D point 0 of image 10 is 77"),
            "{e}"
        );
    }
}
