//! COLMAP sparse models (`cameras`, `images`, `points3D`), text and binary, as COLMAP 3.8
//! writes them. Poses are world-to-camera (`cam_from_world`), quaternions `qw, qx, qy, qz`.
//!
//! Text files are written with the shortest decimal form that parses back to the same `f64`, so
//! text → binary (by COLMAP's `model_converter`) → our reader gives identical numbers.

mod binary;
mod run;
mod text;

pub use run::{
    ColmapOptions, ColmapProgress, ColmapRunError, colmap_available, parse_progress,
    run_colmap_sfm, run_colmap_sfm_with,
};

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector2;

pub use crate::camera::convert::{ColmapCamera, ColmapModel};
use crate::geometry::Rigid3;
use crate::geometry::pose::{colmap_from_rigid, rigid_from_colmap};

use super::error::{Location, ReadError, ReadErrorKind, WriteError};

/// A COLMAP camera id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CameraId(pub u32);
/// A COLMAP image id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ImageId(pub u32);
/// A COLMAP 3D point id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Point3dId(pub u64);

/// One 2D feature of an image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point2D {
    /// Pixel position (COLMAP convention: pixel centres at half-integers).
    pub uv: Vector2<f64>,
    /// The 3D point it observes, if triangulated.
    pub point3d_id: Option<Point3dId>,
}

/// A registered image.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Rotation of `cam_from_world`, `(qw, qx, qy, qz)` as stored.
    pub qvec: [f64; 4],
    /// Translation of `cam_from_world`.
    pub tvec: [f64; 3],
    /// Its camera.
    pub camera_id: CameraId,
    /// File name relative to the image folder.
    pub name: String,
    /// Its 2D features.
    pub points2d: Vec<Point2D>,
}

impl Image {
    /// The pose `cam_from_world`.
    #[must_use]
    pub fn cam_from_world(&self) -> Rigid3 {
        rigid_from_colmap(self.qvec, self.tvec)
    }

    /// Sets the pose from `cam_from_world`.
    pub fn set_cam_from_world(&mut self, pose: &Rigid3) {
        (self.qvec, self.tvec) = colmap_from_rigid(pose);
    }
}

/// One observation of a 3D point: image and index of the 2D feature in it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TrackElement {
    /// The image.
    pub image_id: ImageId,
    /// Index into the image's `points2d`.
    pub point2d_idx: u32,
}

/// A triangulated point with its track.
#[derive(Clone, Debug, PartialEq)]
pub struct Point3D {
    /// World position.
    pub xyz: [f64; 3],
    /// Colour.
    pub rgb: [u8; 3],
    /// Mean reprojection error (px).
    pub error: f64,
    /// Observations.
    pub track: Vec<TrackElement>,
}

/// A COLMAP sparse model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Reconstruction {
    /// Cameras by id.
    pub cameras: BTreeMap<CameraId, ColmapCamera>,
    /// Registered images by id.
    pub images: BTreeMap<ImageId, Image>,
    /// 3D points by id.
    pub points3d: BTreeMap<Point3dId, Point3D>,
}

/// Where the records of a model were read, for the errors found once every file is read.
#[derive(Clone, Debug, Default)]
pub(crate) struct Locations {
    /// Per image: where its record starts, and where its 2D points are (text: the POINTS2D
    /// line; binary: the byte of the point count).
    pub images: BTreeMap<ImageId, (Location, Location)>,
    /// Per 3D point: where its record starts.
    pub points: BTreeMap<Point3dId, Location>,
}

/// The format of a sparse model on disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelFormat {
    /// `cameras.txt`, `images.txt`, `points3D.txt`.
    Text,
    /// `cameras.bin`, `images.bin`, `points3D.bin`.
    Binary,
}

impl ModelFormat {
    /// The model's three files in this format: cameras, images, points.
    #[must_use]
    pub fn files(self) -> [&'static str; 3] {
        match self {
            ModelFormat::Text => ["cameras.txt", "images.txt", "points3D.txt"],
            ModelFormat::Binary => ["cameras.bin", "images.bin", "points3D.bin"],
        }
    }
}

/// The bytes of a model file.
fn load(path: &Path) -> Result<Vec<u8>, ReadError> {
    std::fs::read(path).map_err(|e| super::error::open_error(path, e))
}

impl Reconstruction {
    /// The model restricted to the images whose flag in `keep` (one per image, in image-id
    /// order) is set: feature tracks shortened to those images, points left with fewer than two
    /// observations dropped.
    #[must_use]
    pub fn with_images(&self, keep: &[bool]) -> Reconstruction {
        let kept: std::collections::BTreeSet<ImageId> = self
            .images
            .keys()
            .zip(keep)
            .filter(|(_, k)| **k)
            .map(|(id, _)| *id)
            .collect();
        let mut out = self.clone();
        out.images.retain(|id, _| kept.contains(id));
        for p in out.points3d.values_mut() {
            p.track.retain(|e| kept.contains(&e.image_id));
        }
        out.points3d.retain(|_, p| p.track.len() >= 2);
        out
    }

    /// Reads a model folder, binary if `cameras.bin` exists (as COLMAP does), text otherwise.
    ///
    /// # Errors
    ///
    /// [`ReadError`] naming the file and line (text) or byte (binary) of the first problem,
    /// including references to cameras, images or points that do not exist.
    pub fn read(dir: &Path) -> Result<Self, ReadError> {
        if !dir.is_dir() {
            return Err(ReadError::new(dir, ReadErrorKind::NotFound));
        }
        if dir.join("cameras.bin").is_file() {
            Self::read_format(dir, ModelFormat::Binary)
        } else if dir.join("cameras.txt").is_file() {
            Self::read_format(dir, ModelFormat::Text)
        } else {
            Err(ReadError::new(
                dir,
                ReadErrorKind::Invalid(
                    "not a COLMAP sparse model folder: no cameras.bin or cameras.txt".into(),
                ),
            ))
        }
    }

    /// The model's image ids in the order of its images file (binary if `cameras.bin` exists).
    /// COLMAP's dense workspace numbers images in this order (`fused.ply.vis` refers to images
    /// by their position in it), and COLMAP 3.8 writes images in hash-map order, not by id.
    ///
    /// # Errors
    ///
    /// As [`Reconstruction::read`].
    pub fn image_file_order(dir: &Path) -> Result<Vec<ImageId>, ReadError> {
        if dir.join("cameras.bin").is_file() {
            let path = dir.join(ModelFormat::Binary.files()[1]);
            Ok(binary::read_images(&path, &load(&path)?)?.order)
        } else {
            let path = dir.join(ModelFormat::Text.files()[1]);
            Ok(text::read_images(&path, &load(&path)?)?.order)
        }
    }

    /// Reads a model folder in the given format.
    ///
    /// # Errors
    ///
    /// As [`Reconstruction::read`].
    pub fn read_format(dir: &Path, format: ModelFormat) -> Result<Self, ReadError> {
        let [cameras, images, points] = format.files().map(|f| load(&dir.join(f)));
        Self::parse(dir, format, [&cameras?, &images?, &points?])
    }

    /// Parses a model held in memory: the bytes of its three files (`cameras`, `images`,
    /// `points3D`, in that order) in `format`; `dir` names the files in errors. The same checks
    /// as [`Reconstruction::read`].
    ///
    /// # Errors
    ///
    /// As [`Reconstruction::read`].
    pub fn parse(dir: &Path, format: ModelFormat, files: [&[u8]; 3]) -> Result<Self, ReadError> {
        let (model, locations) = match format {
            ModelFormat::Text => text::parse(dir, files)?,
            ModelFormat::Binary => binary::parse(dir, files)?,
        };
        model.check_references(dir, format, &locations)?;
        Ok(model)
    }

    /// Writes the model into `dir` (created if needed), each file atomically.
    ///
    /// # Errors
    ///
    /// [`WriteError`] naming the file.
    pub fn write(&self, dir: &Path, format: ModelFormat) -> Result<(), WriteError> {
        std::fs::create_dir_all(dir).map_err(|e| WriteError::new(dir, e))?;
        match format {
            ModelFormat::Text => text::write(self, dir),
            ModelFormat::Binary => binary::write(self, dir),
        }
    }

    /// Checks that every id a model refers to exists (images → cameras, points2D ↔ points3D),
    /// naming the line (text) or byte (binary) where the reference was read.
    fn check_references(
        &self,
        dir: &Path,
        format: ModelFormat,
        locations: &Locations,
    ) -> Result<(), ReadError> {
        let [cameras, images, points] = format.files();
        let ext = &cameras[cameras.len() - 3..];
        let images_file = dir.join(images);
        let points_file = dir.join(points);
        let at = |path: &Path, location: Option<&Location>, message: String| ReadError {
            path: path.to_path_buf(),
            location: location.copied(),
            kind: ReadErrorKind::Invalid(message),
        };
        for (id, image) in &self.images {
            let (record, points) = locations
                .images
                .get(id)
                .map_or((None, None), |(r, p)| (Some(r), Some(p)));
            if !self.cameras.contains_key(&image.camera_id) {
                return Err(at(
                    &images_file,
                    record,
                    format!(
                        "image {} refers to camera {}, which cameras.{ext} does not define",
                        id.0, image.camera_id.0
                    ),
                ));
            }
            if let Some((k, p)) = image.points2d.iter().enumerate().find_map(|(k, p)| {
                p.point3d_id
                    .filter(|pid| !self.points3d.contains_key(pid))
                    .map(|pid| (k, pid))
            }) {
                return Err(at(
                    &images_file,
                    points,
                    format!(
                        "field POINT3D_ID of 2D point {k} of image {} is {}, which points3D.{ext} does not define",
                        id.0, p.0
                    ),
                ));
            }
        }
        for (id, point) in &self.points3d {
            let record = locations.points.get(id);
            for el in &point.track {
                let Some(image) = self.images.get(&el.image_id) else {
                    return Err(at(
                        &points_file,
                        record,
                        format!(
                            "point {} is observed in image {}, which images.{ext} does not define",
                            id.0, el.image_id.0
                        ),
                    ));
                };
                if el.point2d_idx as usize >= image.points2d.len() {
                    return Err(at(
                        &points_file,
                        record,
                        format!(
                            "point {} refers to 2D point {} of image {}, which has {}",
                            id.0,
                            el.point2d_idx,
                            el.image_id.0,
                            image.points2d.len()
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The image called `name`, if registered.
    #[must_use]
    pub fn image_by_name(&self, name: &str) -> Option<(ImageId, &Image)> {
        self.images
            .iter()
            .find(|(_, im)| im.name == name)
            .map(|(id, im)| (*id, im))
    }
}

/// The images file as read: images by id, ids in file order, and where each was read.
pub(crate) struct ImagesRead {
    /// Images by id.
    pub images: BTreeMap<ImageId, Image>,
    /// Ids in the order of the file.
    pub order: Vec<ImageId>,
    /// Per image: record and 2D points ([`Locations::images`]).
    pub locations: BTreeMap<ImageId, (Location, Location)>,
}

/// What is wrong with a camera's size or focal length, if anything: `(field, value,
/// expected)`. A camera is at most [`crate::io::frames::MAX_FRAME_PIXELS`] pixels, each side
/// at most [`crate::io::frames::MAX_FRAME_SIDE_PX`], with positive finite focal lengths.
pub(crate) fn camera_problem(cam: &ColmapCamera) -> Option<(&'static str, String, &'static str)> {
    use crate::io::frames::{MAX_FRAME_PIXELS, MAX_FRAME_SIDE_PX};
    let side_ok = |v: u64| (1..=u64::from(MAX_FRAME_SIDE_PX)).contains(&v);
    if !side_ok(cam.width) {
        return Some(("WIDTH", cam.width.to_string(), "a width from 1 to 65535 px"));
    }
    if !side_ok(cam.height) {
        return Some((
            "HEIGHT",
            cam.height.to_string(),
            "a height from 1 to 65535 px",
        ));
    }
    if cam.width * cam.height > MAX_FRAME_PIXELS {
        return Some((
            "WIDTH",
            format!(
                "{} (x {} = {} px)",
                cam.width,
                cam.height,
                cam.width * cam.height
            ),
            "a frame of at most 100000000 pixels",
        ));
    }
    let focal: &[&'static str] = match cam.model {
        ColmapModel::SimplePinhole
        | ColmapModel::SimpleRadial
        | ColmapModel::Radial
        | ColmapModel::SimpleRadialFisheye
        | ColmapModel::RadialFisheye => &["PARAMS[0] (f)"],
        _ => &["PARAMS[0] (fx)", "PARAMS[1] (fy)"],
    };
    for (k, field) in focal.iter().enumerate() {
        let f = cam.params.get(k).copied().unwrap_or(f64::NAN);
        if !(f.is_finite() && f > 0.0) {
            return Some((field, f.to_string(), "a positive focal length (px)"));
        }
    }
    None
}

/// Writes a `cameras.txt` holding just these cameras (atomically).
///
/// # Errors
///
/// [`WriteError`] naming the file.
pub fn write_cameras_text(
    path: &Path,
    cameras: &BTreeMap<CameraId, ColmapCamera>,
) -> Result<(), WriteError> {
    text::write_cameras(path, cameras)
}

/// The `cameras.txt` line of one camera: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`, numbers in
/// their shortest exact form.
#[must_use]
pub fn camera_text_line(id: CameraId, camera: &ColmapCamera) -> String {
    text::camera_line(id, camera)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small model exercising every field, including an image with no points and a point
    /// with a long track.
    pub(crate) fn sample() -> Reconstruction {
        let mut m = Reconstruction::default();
        m.cameras.insert(
            CameraId(1),
            ColmapCamera {
                model: ColmapModel::SimpleRadial,
                width: 3840,
                height: 2160,
                params: vec![3012.345678901234, 1920.0, 1080.0, -0.0123456789],
            },
        );
        m.cameras.insert(
            CameraId(7),
            ColmapCamera {
                model: ColmapModel::FullOpencv,
                width: 640,
                height: 480,
                params: (0..12).map(|k| 0.1 * f64::from(k) + 1.0 / 3.0).collect(),
            },
        );
        m.images.insert(
            ImageId(3),
            Image {
                qvec: [0.851773, 0.0165051, 0.503764, -0.142941],
                tvec: [-0.737434, 1.02973, 3.74354],
                camera_id: CameraId(1),
                name: "frame_0003.png".into(),
                points2d: vec![
                    Point2D {
                        uv: Vector2::new(2362.39, 248.498),
                        point3d_id: Some(Point3dId(5)),
                    },
                    Point2D {
                        uv: Vector2::new(1784.7, 268.254),
                        point3d_id: None,
                    },
                    Point2D {
                        uv: Vector2::new(0.1 + 0.2, 1e-300),
                        point3d_id: Some(Point3dId(9)),
                    },
                ],
            },
        );
        m.images.insert(
            ImageId(4),
            Image {
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.0, 0.0, 0.0],
                camera_id: CameraId(7),
                name: "sub/dir_4.jpg".into(),
                points2d: vec![],
            },
        );
        m.images.insert(
            ImageId(10),
            Image {
                qvec: [0.5, 0.5, -0.5, 0.5],
                tvec: [1.5, -2.25, 1e-7],
                camera_id: CameraId(1),
                name: "frame_0010.png".into(),
                points2d: vec![Point2D {
                    uv: Vector2::new(5.5, 6.5),
                    point3d_id: Some(Point3dId(5)),
                }],
            },
        );
        m.points3d.insert(
            Point3dId(5),
            Point3D {
                xyz: [1.67241, 0.292931, 0.609726],
                rgb: [115, 121, 122],
                error: 1.33927,
                track: vec![
                    TrackElement {
                        image_id: ImageId(3),
                        point2d_idx: 0,
                    },
                    TrackElement {
                        image_id: ImageId(10),
                        point2d_idx: 0,
                    },
                ],
            },
        );
        m.points3d.insert(
            Point3dId(9),
            Point3D {
                xyz: [-1e10, 2.0 / 3.0, 0.0],
                rgb: [0, 255, 1],
                error: 0.0,
                track: vec![TrackElement {
                    image_id: ImageId(3),
                    point2d_idx: 2,
                }],
            },
        );
        m
    }

    #[test]
    fn text_and_binary_round_trip_exactly() {
        let m = sample();
        for format in [ModelFormat::Text, ModelFormat::Binary] {
            let dir = tempfile::tempdir().unwrap();
            m.write(dir.path(), format).unwrap();
            let back = Reconstruction::read_format(dir.path(), format).unwrap();
            assert_eq!(back, m, "{format:?}");
            assert_eq!(Reconstruction::read(dir.path()).unwrap(), m);
        }
    }

    #[test]
    fn dangling_references_name_the_file() {
        let mut m = sample();
        m.images.get_mut(&ImageId(3)).unwrap().camera_id = CameraId(99);
        let dir = tempfile::tempdir().unwrap();
        m.write(dir.path(), ModelFormat::Text).unwrap();
        let err = Reconstruction::read(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("images.txt") && err.contains("camera 99"),
            "{err}"
        );

        let mut m = sample();
        m.points3d.get_mut(&Point3dId(9)).unwrap().track[0].point2d_idx = 7;
        m.write(dir.path(), ModelFormat::Binary).unwrap();
        let err = Reconstruction::read(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("points3D.bin") && err.contains("2D point 7"),
            "{err}"
        );
    }

    #[test]
    fn missing_folder_is_not_found() {
        let err = Reconstruction::read(Path::new("/nonexistent/sparse")).unwrap_err();
        assert!(matches!(err.kind, ReadErrorKind::NotFound));
        let dir = tempfile::tempdir().unwrap();
        let err = Reconstruction::read(dir.path()).unwrap_err().to_string();
        assert!(err.contains("no cameras.bin or cameras.txt"), "{err}");
    }
}
