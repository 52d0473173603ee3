//! The adjustment problems of the calibration loop: the feature tracks of Algorithm 1 step 4
//! ([`feature_problem`], [`adjust_feature_tracks`]) and, each iteration, the target problem of
//! step 6 on the frames that see enough targets, with the views' targets in the neighbouring
//! video frames that tie a rolling shutter's motions to time.

use nalgebra::{Vector2, Vector3};

use super::calibration::intrinsics_of;
use super::{CalibrateConfig, CalibrateError, CalibrationInput, NeighbourLinks};
use crate::adjust::{
    AdjustConfig, AdjustSummary, BrownModel, Loss, Observation, Problem, free_network_datum,
};
use crate::calibrate::matching::Matching;
use crate::calibrate::refine::Algorithm1;
use crate::calibrate::views::{FrameCamera, TargetObservation};
use crate::camera::{Intrinsics, Term};
use crate::geometry::Rigid3;
use crate::io::colmap::Reconstruction;

/// The target adjustment of one iteration, on the frames that observe enough targets.
pub(super) struct TargetProblem {
    pub(super) problem: Problem<BrownModel>,
    /// Per problem camera, its frame (model order).
    pub(super) frames: Vec<usize>,
    /// Frames left out: too few target observations to fix their pose.
    pub(super) dropped_frames: Vec<usize>,
    /// The views' targets seen in the frames' neighbours in the video, each at its time
    /// offset: they tie a rolling-shutter model's motions to time.
    pub(super) neighbour_observations: Vec<Observation>,
}

/// The frames' detections linked to their neighbours' ([`crate::calibrate::neighbours::associate`]).
pub(super) fn neighbour_links(input: &CalibrationInput<'_>) -> Vec<NeighbourLinks> {
    use rayon::prelude::*;
    if input.neighbours.is_empty() {
        return vec![Vec::new(); input.detections.len()];
    }
    input
        .detections
        .par_iter()
        .zip(input.neighbours)
        .map(|(frame, neighbours)| {
            neighbours
                .iter()
                .map(|n| {
                    (
                        n.dt_s,
                        crate::calibrate::neighbours::associate(frame, &n.ellipses),
                    )
                })
                .collect()
        })
        .collect()
}

/// Fewest target observations a frame needs in the adjustment: three points fix a pose, six
/// leave it redundancy (a frame with fewer has its pose undetermined or unchecked, and a free
/// network with such a pose is singular).
pub const MIN_FRAME_OBSERVATIONS: usize = 6;

/// The target adjustment: every track with enough corrected views, observed at Algorithm 3's
/// centre mapped back into observed pixels, on the frames that see at least
/// [`MIN_FRAME_OBSERVATIONS`] of them (frames with fewer are left out, and the tracks that
/// then have too few views with them, until both hold).
pub(super) fn target_problem(
    m: &Matching,
    cameras: &[FrameCamera],
    obs: &[Vec<TargetObservation>],
    input: &CalibrationInput<'_>,
    links: &[NeighbourLinks],
    config: &CalibrateConfig,
) -> Result<TargetProblem, CalibrateError> {
    /// A target's point and its (frame, observed pixel, detection index) views.
    type Views = (Vector3<f64>, Vec<(usize, Vector2<f64>, usize)>);
    let mut tracks: Vec<Views> = m
        .tracks
        .iter()
        .map(|track| {
            let views = track
                .views
                .iter()
                .filter_map(|v| {
                    let c = v.corrected?;
                    let uv = cameras[v.frame].distort(&c)?;
                    Some((v.frame, uv, obs[v.frame].get(v.obs)?.index))
                })
                .collect();
            (track.point.coords, views)
        })
        .collect();
    let mut keep_frame = vec![true; cameras.len()];
    loop {
        tracks.retain(|(_, views)| views.len() >= config.min_views);
        let mut count = vec![0usize; cameras.len()];
        for (_, views) in &tracks {
            for (frame, ..) in views {
                count[*frame] += 1;
            }
        }
        let mut changed = false;
        for (keep, n) in keep_frame.iter_mut().zip(&count) {
            if *keep && *n < MIN_FRAME_OBSERVATIONS {
                *keep = false;
                changed = true;
            }
        }
        if !changed {
            break;
        }
        for (_, views) in &mut tracks {
            views.retain(|(frame, ..)| keep_frame[*frame]);
        }
    }
    if tracks.len() < config.min_targets {
        return Err(CalibrateError::TooFew {
            what: "targets with enough corrected views",
            found: tracks.len(),
            required: config.min_targets,
        });
    }
    let frames: Vec<usize> = (0..cameras.len()).filter(|&k| keep_frame[k]).collect();
    let dropped_frames = (0..cameras.len()).filter(|&k| !keep_frame[k]).collect();
    let mut camera_of = vec![usize::MAX; cameras.len()];
    for (k, &f) in frames.iter().enumerate() {
        camera_of[f] = k;
    }
    let mut points = Vec::with_capacity(tracks.len());
    let mut observations = Vec::new();
    let mut neighbour_observations = Vec::new();
    for (point, views) in tracks {
        let id = points.len();
        points.push(point);
        for (frame, uv, index) in views {
            observations.push(Observation {
                camera: camera_of[frame],
                point: id,
                uv,
                weight: 1.0,
                time_offset_s: 0.0,
            });
            // The same target in the neighbours: its detected centre moved by the same
            // eccentricity correction as the frame's (the view changes by a fraction of a
            // degree in 1/fps).
            let Some(detected) = input.detections[frame].get(index) else {
                continue;
            };
            let correction = uv - detected.centre();
            let neighbours = input.neighbours.get(frame).map_or(&[][..], Vec::as_slice);
            for ((dt, link), n) in links[frame].iter().zip(neighbours) {
                if let Some(e) = link
                    .get(index)
                    .copied()
                    .flatten()
                    .and_then(|j| n.ellipses.get(j))
                {
                    neighbour_observations.push(Observation {
                        camera: camera_of[frame],
                        point: id,
                        uv: e.centre() + correction,
                        weight: 1.0,
                        time_offset_s: *dt,
                    });
                }
            }
        }
    }
    let intrinsics = cameras[0].intrinsics;
    let problem = Problem::new(
        BrownModel::GLOBAL_SHUTTER,
        frames.iter().map(|&f| cameras[f].cam_from_world).collect(),
        Vec::new(),
        intrinsics.to_array().to_vec(),
        points,
        observations,
    )?;
    Ok(TargetProblem {
        problem,
        frames,
        dropped_frames,
        neighbour_observations,
    })
}

/// The inlier feature tracks of three or more views as an adjustment problem at the cameras'
/// poses and intrinsics (all free): Algorithm 1 step 4's problem.
///
/// # Errors
///
/// [`CalibrateError`] for fewer than seven tracks with three inlier views.
pub fn feature_problem(
    model: &Reconstruction,
    a1: &Algorithm1,
    cameras: &[FrameCamera],
) -> Result<Problem<BrownModel>, CalibrateError> {
    let index_of = crate::calibrate::refine::frame_index(&a1.frames);
    let mut points = Vec::new();
    let mut observations = Vec::new();
    for track in &a1.tracks {
        let Some(p3) = model.points3d.get(&track.point3d_id) else {
            continue;
        };
        let elems: Vec<(usize, Vector2<f64>)> = p3
            .track
            .iter()
            .zip(&track.inliers)
            .filter(|(_, inlier)| **inlier)
            .filter_map(|(e, _)| {
                let frame = *index_of.get(&e.image_id)?;
                let uv = model.images[&e.image_id]
                    .points2d
                    .get(e.point2d_idx as usize)?
                    .uv;
                Some((frame, uv))
            })
            .collect();
        if elems.len() < 3 {
            continue;
        }
        let id = points.len();
        points.push(track.point.coords);
        for (frame, uv) in elems {
            observations.push(Observation {
                camera: frame,
                point: id,
                uv,
                weight: 1.0,
                time_offset_s: 0.0,
            });
        }
    }
    if points.len() < 7 {
        return Err(CalibrateError::TooFew {
            what: "feature tracks with three or more inlier views",
            found: points.len(),
            required: 7,
        });
    }
    let intrinsics = cameras[0].intrinsics;
    let problem = Problem::new(
        BrownModel::GLOBAL_SHUTTER,
        cameras.iter().map(|c| c.cam_from_world).collect(),
        Vec::new(),
        intrinsics.to_array().to_vec(),
        points,
        observations,
    )?;
    Ok(problem)
}

/// The intrinsics Algorithm 1 step 4 adjusts with the poses in a calibration.
pub const FEATURE_ADJUSTMENT_TERMS: [Term; 5] = [Term::C, Term::U0, Term::V0, Term::K1, Term::K2];

/// Algorithm 1 step 4: the feature tracks' inlier observations adjusted with the poses, the
/// points and the intrinsics `free` (the others held at the cameras' values; Huber loss at 3σ of
/// Algorithm 1's reprojection σ), free network. With `free` empty it is the site's adjustment
/// with a device profile's intrinsics fixed; with c, k1, k2 it is COLMAP's in-situ radial
/// self-calibration.
///
/// # Errors
///
/// [`CalibrateError`] for fewer than seven tracks with three inlier views, or a failed
/// adjustment.
pub fn adjust_feature_tracks(
    model: &Reconstruction,
    a1: &Algorithm1,
    cameras: &[FrameCamera],
    free: &[Term],
    adjust: &AdjustConfig,
) -> Result<(AdjustSummary, Intrinsics, Vec<Rigid3>), CalibrateError> {
    let mut problem = feature_problem(model, a1, cameras)?;
    problem.fixed.global = Term::ALL
        .iter()
        .filter(|t| !free.contains(t))
        .map(|t| t.index())
        .collect();
    let summary = adjust_tracks_free_network(&mut problem, a1.reprojection_sigma, adjust)?;
    Ok((summary, intrinsics_of(&problem), problem.cam_from_world))
}

/// The feature adjustment's Huber threshold in units of the tracks' robust reprojection σ,
/// and that σ's floor (px), so that tracks located nearly exactly do not turn every residual
/// into an outlier.
const FEATURE_HUBER_SIGMAS: f64 = 3.0;
const MIN_FEATURE_SIGMA_PX: f64 = 0.1;

/// Adjusts a feature-track problem (its fixed parameters already set) with a Huber loss at
/// 3·σ (σ the tracks' robust reprojection σ, at least 0.1 px) and puts the result back in
/// the frame of its starting points (free-network datum): the tail shared by
/// [`adjust_feature_tracks`] and the rolling-shutter poses.
///
/// # Errors
///
/// [`CalibrateError`] when the adjustment or the datum fails.
pub(crate) fn adjust_tracks_free_network<M: crate::adjust::CameraModel>(
    problem: &mut Problem<M>,
    sigma_px: f64,
    adjust: &AdjustConfig,
) -> Result<AdjustSummary, CalibrateError> {
    let reference = problem.points.clone();
    let adjust = AdjustConfig {
        loss: Loss::Huber(FEATURE_HUBER_SIGMAS * sigma_px.max(MIN_FEATURE_SIGMA_PX)),
        ..*adjust
    };
    let summary = crate::adjust::bundle_adjust(problem, &adjust)?;
    free_network_datum(problem, &reference)?;
    Ok(summary)
}
