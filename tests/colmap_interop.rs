//! COLMAP sparse models written by us are read by the real COLMAP 3.8, converted by it, and read
//! back identically; and models COLMAP writes are read by us.
//!
//! Needs `colmap` on PATH. Outside CI the test is skipped (with a message) when it is missing;
//! with `CI=true` a missing COLMAP is a failure, so CI can never pass without running it.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::Path;
use std::process::Command;

use nalgebra::{UnitQuaternion, Vector2};
use pipemeasure::geometry::pose::colmap_from_rigid;
use pipemeasure::io::colmap::{
    CameraId, ColmapCamera, ColmapModel, Image, ImageId, ModelFormat, Point2D, Point3D, Point3dId,
    Reconstruction, TrackElement,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn colmap(args: &[&str]) {
    let out = Command::new("colmap").args(args).output().unwrap();
    assert!(
        out.status.success(),
        "colmap {args:?} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A random but valid model: every convertible camera model, images with 2D points (some
/// untriangulated), points with tracks. Quaternions come from nalgebra's unit quaternions.
fn random_model(seed: u64) -> Reconstruction {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut m = Reconstruction::default();
    for (k, model) in ColmapModel::ALL.into_iter().enumerate() {
        let params = (0..model.num_params())
            .map(|_| rng.random_range(-0.1..0.1) + 1.0)
            .collect();
        m.cameras.insert(
            CameraId(k as u32 + 1),
            ColmapCamera {
                model,
                width: 3840,
                height: 2160,
                params,
            },
        );
    }
    for i in 0..20u32 {
        let q = UnitQuaternion::from_euler_angles(
            rng.random_range(-3.0..3.0),
            rng.random_range(-1.5..1.5),
            rng.random_range(-3.0..3.0),
        );
        let pose = nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::new(
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
                rng.random_range(-5.0..5.0),
            ),
            q,
        );
        let (qvec, tvec) = colmap_from_rigid(&pose);
        m.images.insert(
            ImageId(i * 3 + 1),
            Image {
                qvec,
                tvec,
                camera_id: CameraId(i % 11 + 1),
                name: format!("frames/frame_{i:04}.png"),
                points2d: Vec::new(),
            },
        );
    }
    let image_ids: Vec<ImageId> = m.images.keys().copied().collect();
    for p in 0..300u64 {
        let mut track = Vec::new();
        for _ in 0..rng.random_range(2..6) {
            let id = image_ids[rng.random_range(0..image_ids.len())];
            let image = m.images.get_mut(&id).unwrap();
            track.push(TrackElement {
                image_id: id,
                point2d_idx: image.points2d.len() as u32,
            });
            image.points2d.push(Point2D {
                uv: Vector2::new(rng.random_range(0.0..3840.0), rng.random_range(0.0..2160.0)),
                point3d_id: Some(Point3dId(p * 7 + 2)),
            });
            // An untriangulated feature beside it.
            image.points2d.push(Point2D {
                uv: Vector2::new(rng.random_range(0.0..3840.0), rng.random_range(0.0..2160.0)),
                point3d_id: None,
            });
        }
        m.points3d.insert(
            Point3dId(p * 7 + 2),
            Point3D {
                xyz: [
                    rng.random_range(-10.0..10.0),
                    rng.random_range(-10.0..10.0),
                    rng.random_range(0.0..20.0),
                ],
                rgb: [rng.random(), rng.random(), rng.random()],
                error: rng.random_range(0.0..2.0),
                track,
            },
        );
    }
    m
}

fn path_str(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn colmap_converts_our_text_model_to_binary_that_reads_back_identically() {
    if !common::colmap_available() {
        return;
    }
    let model = random_model(11);
    let dir = tempfile::tempdir().unwrap();
    let txt = dir.path().join("txt");
    let bin = dir.path().join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    model.write(&txt, ModelFormat::Text).unwrap();
    colmap(&[
        "model_converter",
        "--input_path",
        path_str(&txt),
        "--output_path",
        path_str(&bin),
        "--output_type",
        "BIN",
    ]);
    let back = Reconstruction::read_format(&bin, ModelFormat::Binary).unwrap();
    assert_eq!(back.cameras, model.cameras);
    assert_eq!(back.points3d, model.points3d);
    assert_eq!(back.images.len(), model.images.len());
    for (id, im) in &model.images {
        let b = &back.images[id];
        assert_eq!(
            (b.camera_id, &b.name, &b.points2d, b.tvec),
            (im.camera_id, &im.name, &im.points2d, im.tvec)
        );
        // COLMAP renormalises quaternions when it reads them: equal to the last bits.
        for k in 0..4 {
            assert!(
                (b.qvec[k] - im.qvec[k]).abs() <= 4.0 * f64::EPSILON,
                "image {} q{k}",
                id.0
            );
        }
    }
}

#[test]
fn we_read_binary_and_text_models_written_by_colmap() {
    if !common::colmap_available() {
        return;
    }
    let model = random_model(12);
    let dir = tempfile::tempdir().unwrap();
    let ours = dir.path().join("ours");
    let theirs_txt = dir.path().join("theirs_txt");
    let theirs_bin = dir.path().join("theirs_bin");
    std::fs::create_dir_all(&theirs_txt).unwrap();
    std::fs::create_dir_all(&theirs_bin).unwrap();
    model.write(&ours, ModelFormat::Binary).unwrap();
    colmap(&[
        "model_converter",
        "--input_path",
        path_str(&ours),
        "--output_path",
        path_str(&theirs_bin),
        "--output_type",
        "BIN",
    ]);
    colmap(&[
        "model_converter",
        "--input_path",
        path_str(&ours),
        "--output_path",
        path_str(&theirs_txt),
        "--output_type",
        "TXT",
    ]);
    let bin = Reconstruction::read_format(&theirs_bin, ModelFormat::Binary).unwrap();
    let txt = Reconstruction::read_format(&theirs_txt, ModelFormat::Text).unwrap();
    assert_eq!(bin.cameras, model.cameras);
    assert_eq!(bin.points3d, model.points3d);
    assert_eq!(
        bin.images.keys().collect::<Vec<_>>(),
        model.images.keys().collect::<Vec<_>>()
    );
    // COLMAP's text writer prints 17 significant digits: equal to the last bit or two.
    assert_eq!(txt.images.len(), model.images.len());
    for (id, cam) in &model.cameras {
        let t = &txt.cameras[id];
        assert_eq!(
            (t.model, t.width, t.height),
            (cam.model, cam.width, cam.height)
        );
        for (a, b) in t.params.iter().zip(&cam.params) {
            assert!(
                (a - b).abs() <= 2.0 * f64::EPSILON * b.abs(),
                "camera {} {a} vs {b}",
                id.0
            );
        }
    }
    for (id, p) in &model.points3d {
        assert_eq!(txt.points3d[id].track, p.track);
    }
}

#[test]
fn colmap_model_analyzer_accepts_our_model() {
    if !common::colmap_available() {
        return;
    }
    let model = random_model(13);
    let dir = tempfile::tempdir().unwrap();
    model.write(dir.path(), ModelFormat::Text).unwrap();
    colmap(&["model_analyzer", "--path", path_str(dir.path())]);
}
