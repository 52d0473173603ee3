//! Running a simulation end to end: build the scene, render the frames in parallel, compute the
//! truth, make the sparse model, and write everything into one folder.
//!
//! ```text
//! OUT/frames/frame_0001.png …   rendered frames (PNG, or JPEG with a quality)
//! OUT/truth.json                 schema pipemeasure.truth/1 (see sim::truth)
//! OUT/sparse/{cameras,images,points3D}.txt   the SfM stand-in (or COLMAP's model)
//! site only:
//! OUT/tls_targets.csv            id,x,y,z of the wall targets (TLS frame, with TLS noise)
//! OUT/tls_scan.ply               the TLS cloud of pipes, wall and floor
//! OUT/dense/observations.bin     dense surface points with noisy pixel observations
//! OUT/dense/fused.ply            the dense cloud triangulated from them (SfM frame)
//! ```
//!
//! With `video` options the frames are filmed by a moving rolling-shutter camera instead
//! ([`super::video`], which lists the extra outputs: neighbours, `frames/frames.json`, the
//! full-rate video); without them (the default) every frame is a still, global-shutter frame at
//! its station, as before.
//!
//! Every output is a pure function of the options and the seed: the same seed gives
//! byte-identical files whatever the number of threads.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::lab::{LabConfig, Station};
pub use super::options::{SfmSource, SimError, SimulateOptions};
use super::render::{RayGrid, exposure_gain, render_frame};
use super::scene::Scene;
use super::sfm::{stand_in, stand_in_observed};
use super::truth::{TRUTH_SCHEMA, Truth, TruthCamera, frame_truth};
use super::video::Filming;
use crate::camera::BrownCamera;
use crate::io::WriteError;
use crate::io::atomic::write_bytes_atomic;
use crate::io::colmap::ModelFormat;

/// Texture resolution for a camera: about 0.6 px at 2 m, between 0.8 mm and 10 mm.
#[must_use]
pub fn texel_size(camera: &BrownCamera) -> f64 {
    (2.0 / camera.intrinsics.c * 0.6).clamp(0.0008, 0.01)
}

/// Renders `stations` into `out/frames` and returns the truth frames, in order.
///
/// # Errors
///
/// A frame that cannot be encoded or written.
pub fn render_frames(
    scene: &Scene,
    camera: &BrownCamera,
    stations: &[Station],
    gain: f64,
    options: &SimulateOptions,
    out: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Vec<super::truth::TruthFrame>, SimError> {
    let frames_dir = out.join("frames");
    std::fs::create_dir_all(&frames_dir).map_err(|e| WriteError::new(&frames_dir, e))?;
    let rays = RayGrid::new(camera);
    let done = std::sync::atomic::AtomicUsize::new(0);
    stations
        .par_iter()
        .enumerate()
        .map(|(k, station)| {
            let name = options.frame_name(k);
            let frame = render_frame(
                scene,
                camera,
                &rays,
                &station.cam_from_world,
                gain,
                &options.render,
                options.seed,
                k as u64,
            )
            .map_err(|source| SimError::Encode {
                name: name.clone(),
                source,
            })?;
            frame.write(&frames_dir.join(&name))?;
            let truth = frame_truth(
                scene,
                camera,
                k as u32 + 1,
                &name,
                &station.cam_from_world,
                station.orientation,
                options.margin_px,
            );
            progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
            Ok(truth)
        })
        .collect()
}

/// Writes the truth file atomically.
///
/// # Errors
///
/// [`WriteError`].
pub fn write_truth(truth: &Truth, out: &Path) -> Result<PathBuf, WriteError> {
    let path = out.join("truth.json");
    let text = serde_json::to_string_pretty(truth)
        .map_err(|e| WriteError::new(&path, std::io::Error::other(e)))?;
    write_bytes_atomic(&path, text.as_bytes())?;
    Ok(path)
}

/// A scene's truth record around its frames and sparse-model truth (no pipes, TLS or dense
/// data: the site adds those).
fn truth_record(
    scene_name: &str,
    options: &SimulateOptions,
    camera: &BrownCamera,
    scene: &Scene,
    frames: Vec<super::truth::TruthFrame>,
    sfm: super::truth::SfmTruth,
    video: Option<super::truth::VideoTruth>,
) -> Truth {
    Truth {
        schema: TRUTH_SCHEMA.into(),
        scene: scene_name.into(),
        seed: options.seed,
        command: options.command.clone(),
        camera: TruthCamera {
            device: options.device.clone(),
            width: camera.width,
            height: camera.height,
            intrinsics: camera.intrinsics,
        },
        render: options.render.clone(),
        margin_px: options.margin_px,
        targets: scene.targets.clone(),
        frames,
        sfm: Some(sfm),
        pipes: Vec::new(),
        tls: None,
        dense: None,
        video,
    }
}

/// What filming a scene produced.
struct Filmed<'a> {
    frames: Vec<super::truth::TruthFrame>,
    /// The stations at the extracted frames' times.
    stations: Vec<Station>,
    sfm: super::truth::SfmTruth,
    video: Option<super::truth::VideoTruth>,
    /// The video's camera, for the site's dense observations.
    filming: Option<Filming<'a>>,
}

/// Renders the frames (stills, or a video when `options.video` is set) and writes the sparse
/// model of the extracted frames; with video, the neighbours and the full-rate video come after
/// the sparse model (COLMAP reads the frames folder recursively).
fn film<'a>(
    scene: &'a Scene,
    camera: &BrownCamera,
    stations: Vec<Station>,
    gain: f64,
    options: &'a SimulateOptions,
    out: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Filmed<'a>, SimError> {
    super::video::clear_video_outputs(out)?;
    if options.video.is_none() {
        let frames = render_frames(scene, camera, &stations, gain, options, out, progress)?;
        let sfm = write_sparse(scene, camera, &stations, None, options, out)?;
        return Ok(Filmed {
            frames,
            stations,
            sfm,
            video: None,
            filming: None,
        });
    }
    let filming = Filming::new(scene, camera, &stations, gain, options)?;
    let stations = filming.stations();
    let mut frames = filming.film_main(out, progress)?;
    let sfm = write_sparse(
        scene,
        camera,
        &stations,
        Some(&filming.sparse_observer()),
        options,
        out,
    )?;
    let video = filming.film_rest(&mut frames, out, progress)?;
    Ok(Filmed {
        frames,
        stations,
        sfm,
        video: Some(video),
        filming: Some(filming),
    })
}

/// The number of frames a simulation renders (progress): the frames, and with video their
/// neighbours and the full-rate video.
///
/// # Errors
///
/// [`SimError`] for bad options.
pub fn frames_to_render(options: &SimulateOptions, frames: usize) -> Result<usize, SimError> {
    let Some(video) = &options.video else {
        return Ok(frames);
    };
    video.validate()?;
    let neighbours = if video.neighbours { 2 * frames } else { 0 };
    let full_rate = if video.full_rate_width.is_some() {
        let last = frames.saturating_sub(1) as f64 * video.interval_s;
        (last * video.frame_rate + 1e-9).floor() as usize + 1
    } else {
        0
    };
    Ok(frames + neighbours + full_rate)
}

/// Simulates the calibration lab into `out`.
///
/// # Errors
///
/// [`SimError`] for bad options, a file that cannot be written, or a failed COLMAP run.
pub fn simulate_lab(
    options: &SimulateOptions,
    lab: &LabConfig,
    out: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Truth, SimError> {
    options.validate()?;
    lab.validate()?;
    let camera = options.camera()?;
    let scene = super::lab::build_scene(lab, texel_size(&camera), options.seed);
    let stations = super::lab::path(lab, options.seed);
    let gain = exposure_gain(
        &options.render,
        super::lab::reference_irradiance(&scene, lab),
    );
    std::fs::create_dir_all(out).map_err(|e| WriteError::new(out, e))?;
    let filmed = film(&scene, &camera, stations, gain, options, out, progress)?;
    let truth = truth_record(
        "lab",
        options,
        &camera,
        &scene,
        filmed.frames,
        filmed.sfm,
        filmed.video,
    );
    write_truth(&truth, out)?;
    Ok(truth)
}

/// The lab's geometry without images: the same truth as [`simulate_lab`] (same scene, path,
/// per-frame target views) and the SfM stand-in's sparse model, in memory. For tests and
/// experiments that start from detections rather than pixels (the truth's `fitted` ellipses
/// are what a perfect detector finds).
///
/// # Errors
///
/// [`SimError`] for bad options.
pub fn lab_geometry(
    options: &SimulateOptions,
    lab: &LabConfig,
) -> Result<(Truth, crate::io::colmap::Reconstruction), SimError> {
    options.validate()?;
    lab.validate()?;
    let camera = options.camera()?;
    let scene = super::lab::build_scene(lab, texel_size(&camera), options.seed);
    let mut stations = super::lab::path(lab, options.seed);
    let filming = match options.video {
        // The gain does not enter the truth.
        Some(_) => Some(Filming::new(&scene, &camera, &stations, 1.0, options)?),
        None => None,
    };
    let (frames, video) = if let Some(filming) = &filming {
        stations = filming.stations();
        (filming.truth_frames(), Some(filming.truth(None)))
    } else {
        let frames = stations
            .par_iter()
            .enumerate()
            .map(|(k, station)| {
                frame_truth(
                    &scene,
                    &camera,
                    k as u32 + 1,
                    &options.frame_name(k),
                    &station.cam_from_world,
                    station.orientation,
                    options.margin_px,
                )
            })
            .collect();
        (frames, None)
    };
    let poses: Vec<_> = stations.iter().map(|s| s.cam_from_world).collect();
    let names: Vec<_> = (0..stations.len()).map(|k| options.frame_name(k)).collect();
    let (model, sfm) = match &filming {
        Some(filming) => stand_in_observed(
            &scene,
            &camera,
            &poses,
            &names,
            &options.sfm,
            options.seed,
            &filming.sparse_observer(),
        ),
        None => stand_in(&scene, &camera, &poses, &names, &options.sfm, options.seed),
    };
    Ok((
        truth_record("lab", options, &camera, &scene, frames, sfm, video),
        model,
    ))
}

/// Site-specific options.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SiteOptions {
    /// Scene content.
    pub site: super::site::SiteConfig,
    /// Dense observations.
    pub dense: super::dense::DenseConfig,
    /// TLS survey.
    pub tls: super::dense::TlsConfig,
    /// A plant room ([`super::plant_site`], drawn from the seed) instead of the mock pipes:
    /// `site.frames` stations on a walk around it, target boards on its walls, the TLS scan
    /// from the room's stations, and `plant.json` ([`super::plant::PlantTruth`]) beside the
    /// truth.
    pub plant: bool,
}

/// Simulates a pipe site into `out`.
///
/// # Errors
///
/// [`SimError`] for bad options, a file that cannot be written, or a failed COLMAP run.
///
/// Kept whole (one function over 150 lines): the site simulation's steps in the order they
/// write their files (scene, frames, SfM, dense cloud, TLS scan, truth), each once.
pub fn simulate_site(
    options: &SimulateOptions,
    site: &SiteOptions,
    out: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Truth, SimError> {
    use super::dense::{fuse, observe_samples, site_samples, tls_scan, tls_targets};
    options.validate()?;
    site.site.validate()?;
    let camera = options.camera()?;
    let room = site.plant.then(|| super::plant::plant_room(options.seed));
    let (scene, stations, reference) = match &room {
        Some(room) => {
            let scene = super::plant_site::build_scene(room, options.seed);
            let stations = super::plant_site::path(room, site.site.frames, options.seed);
            let reference = super::plant_site::reference_irradiance(&scene);
            (scene, stations, reference)
        }
        None => {
            let scene = super::site::build_scene(&site.site, texel_size(&camera), options.seed);
            let reference = super::site::reference_irradiance(&scene);
            (
                scene,
                super::site::path(&site.site, options.seed),
                reference,
            )
        }
    };
    let gain = exposure_gain(&options.render, reference);
    std::fs::create_dir_all(out).map_err(|e| WriteError::new(out, e))?;
    let Filmed {
        frames,
        stations,
        sfm,
        video,
        filming,
    } = film(&scene, &camera, stations, gain, options, out, progress)?;

    // Dense observations and the fused cloud at the sparse model's poses.
    let dense_dir = out.join("dense");
    std::fs::create_dir_all(&dense_dir).map_err(|e| WriteError::new(&dense_dir, e))?;
    let poses: Vec<_> = stations.iter().map(|s| s.cam_from_world).collect();
    let names: Vec<_> = (0..stations.len()).map(|k| options.frame_name(k)).collect();
    let (pipe_spacing, surface_spacing) = site.dense.spacings(camera.width);
    let (samples, labels) = match &room {
        Some(room) => (
            super::plant_site::surface_samples(room, pipe_spacing, surface_spacing),
            super::plant_site::labels(&room.truth),
        ),
        None => site_samples(&scene, &site.site.pipes, pipe_spacing, surface_spacing),
    };
    let still = |f: usize,
                 p: &nalgebra::Point3<f64>,
                 n: &nalgebra::Vector3<f64>,
                 at: &nalgebra::Point3<f64>| {
        let uv = super::sfm::observe(&scene, &camera, &poses[f], p, n)?;
        let eye = crate::geometry::pose::camera_centre(&poses[f]);
        if at == p {
            return Some((uv, eye));
        }
        Some((camera.project_world(&poses[f], &at.coords)?, eye))
    };
    // A video's frames see each point in its own row (the cloud then carries the rolling
    // shutter's distortion, as a dense reconstruction of such frames does).
    let moving = filming.as_ref().map(Filming::dense_observer);
    let observer: &super::dense::Observer<'_> = match &moving {
        Some(moving) => moving,
        None => &still,
    };
    let obs = observe_samples(
        &samples,
        labels,
        observer,
        &names,
        &site.dense,
        options.seed,
    );
    obs.write(&dense_dir.join("observations.bin"))?;
    let model =
        crate::io::colmap::Reconstruction::read_format(&out.join("sparse"), ModelFormat::Text)
            .map_err(|e| SimError::Option {
                field: "sparse",
                reason: e.to_string(),
            })?;
    // As COLMAP's dense reconstruction: through the model's own camera at its poses (frames
    // the SfM did not register have no pose; their observations are left out).
    let sfm_poses: Vec<_> = names
        .iter()
        .map(|n| model.image_by_name(n).map(|(_, im)| im.cam_from_world()))
        .collect();
    // The perturbed-truth stand-in's camera was never adjusted (an EXIF guess): its cloud is
    // fused through the true camera, a dense reconstruction with perfect intrinsics.
    let sfm_camera = match (options.sfm_source, options.sfm.adjust) {
        (SfmSource::StandIn, false) => camera,
        _ => sfm_camera(&model, &camera)?,
    };
    let (fused, frames_of) = fuse(&obs, &sfm_camera, &sfm_poses);
    crate::io::ply::write_binary(&dense_dir.join("fused.ply"), &fused)?;
    // fused.ply.vis: each point's images by position in the model's images file (id order).
    let position: Vec<Option<u32>> = names
        .iter()
        .map(|n| {
            let (id, _) = model.image_by_name(n)?;
            model.images.keys().position(|&i| i == id).map(|k| k as u32)
        })
        .collect();
    let visibility: Vec<Vec<u32>> = frames_of
        .iter()
        .map(|f| f.iter().filter_map(|&k| position[k as usize]).collect())
        .collect();
    crate::io::vis::write(&dense_dir.join("fused.ply.vis"), &visibility)?;

    // TLS scan and targets (a plant room's from its scanner stations, offset as the targets).
    let (scan, plant_truth) = match room {
        Some(room) => {
            let config = super::plant::PlantScanConfig {
                range_noise_m: site.tls.range_noise_m,
                ..super::plant::PlantScanConfig::default()
            };
            let (mut scan, _, truth) = super::plant::scan_into_truth(room, &config, options.seed);
            let offset = nalgebra::Vector3::from(site.tls.offset);
            scan.points.iter_mut().for_each(|p| *p += offset);
            (scan, Some(truth))
        }
        None => (tls_scan(&scene, &site.tls, options.seed), None),
    };
    crate::io::ply::write_binary(&out.join("tls_scan.ply"), &scan)?;
    if let Some(plant) = &plant_truth {
        let json = serde_json::to_vec_pretty(plant)
            .map_err(|e| WriteError::new(out.join("plant.json"), std::io::Error::other(e)))?;
        std::fs::write(out.join("plant.json"), json)
            .map_err(|e| WriteError::new(out.join("plant.json"), e))?;
    }
    let targets: Vec<_> = tls_targets(&scene, &site.tls, options.seed)
        .into_iter()
        .map(|(id, p)| crate::io::tls::TlsTarget {
            id: id.to_string(),
            position: nalgebra::Point3::from(p),
        })
        .collect();
    crate::io::tls::write_targets(&out.join("tls_targets.csv"), &targets)?;

    let truth = Truth {
        pipes: if site.plant {
            Vec::new()
        } else {
            site.site.pipe_truth()
        },
        tls: Some(super::truth::TlsTruth {
            station: plant_truth
                .as_ref()
                .and_then(|p| p.scan.as_ref()?.stations.first().copied())
                .unwrap_or(site.tls.station),
            offset: site.tls.offset,
            range_noise_m: site.tls.range_noise_m,
            target_noise_m: site.tls.target_noise_m,
            points: scan.len(),
        }),
        dense: Some(super::truth::DenseTruth {
            points: obs.points.len(),
            observations: obs.points.iter().map(|p| p.observations.len()).sum(),
            noise_px: site.dense.noise_px,
            fused_points: fused.len(),
            labels: obs.labels.clone(),
        }),
        ..truth_record("site", options, &camera, &scene, frames, sfm, video)
    };
    write_truth(&truth, out)?;
    Ok(truth)
}

/// The sparse model's camera as a Brown camera of the frames' size (what a dense
/// reconstruction of that model triangulates with).
fn sfm_camera(
    model: &crate::io::colmap::Reconstruction,
    camera: &BrownCamera,
) -> Result<BrownCamera, SimError> {
    let cam = model.cameras.values().next().ok_or(SimError::Option {
        field: "sparse",
        reason: "the SfM model has no camera".into(),
    })?;
    let converted =
        crate::camera::convert::brown_from_colmap(cam).map_err(|e| SimError::Option {
            field: "sparse",
            reason: e.to_string(),
        })?;
    Ok(BrownCamera {
        intrinsics: converted.camera.intrinsics,
        ..*camera
    })
}

/// Writes `out/sparse` from the stand-in (its features where `observer` sees them, a video's
/// rolling-shutter pixels; the still frames' when `None`) or from COLMAP.
fn write_sparse(
    scene: &Scene,
    camera: &BrownCamera,
    stations: &[Station],
    observer: Option<&super::sfm::Observer<'_>>,
    options: &SimulateOptions,
    out: &Path,
) -> Result<super::truth::SfmTruth, SimError> {
    let sparse = out.join("sparse");
    match options.sfm_source {
        SfmSource::StandIn => {
            let poses: Vec<_> = stations.iter().map(|s| s.cam_from_world).collect();
            let names: Vec<_> = (0..stations.len()).map(|k| options.frame_name(k)).collect();
            let (model, truth) = match observer {
                Some(observer) => stand_in_observed(
                    scene,
                    camera,
                    &poses,
                    &names,
                    &options.sfm,
                    options.seed,
                    observer,
                ),
                None => stand_in(scene, camera, &poses, &names, &options.sfm, options.seed),
            };
            model.write(&sparse, ModelFormat::Text)?;
            Ok(truth)
        }
        SfmSource::Colmap => {
            let model =
                crate::io::colmap::run_colmap_sfm(&out.join("frames"), &out.join("colmap"))?;
            model.write(&sparse, ModelFormat::Text)?;
            Ok(super::truth::SfmTruth {
                source: "colmap".into(),
                points: model.points3d.len(),
                stand_in: None,
            })
        }
    }
}
