//! The calibration loop (paper, "Summary of Methods", steps 1–7):
//!
//! 1. SfM model (poses, features, an EXIF-like camera);
//! 2. Algorithm 1 steps 1–3: robust `F` per overlapping pair, robust triangulation of the
//!    feature tracks ([`super::refine`]);
//! 3. Algorithm 1 step 4: adjustment on the inlier features only, refining the poses and a
//!    first c, u0, v0, k1, k2;
//! 4. the detected ellipses, undistorted with the current intrinsics;
//! 5. Algorithm 2 (matching) and Algorithm 3 (centre correction) ([`super::matching`]);
//! 6. the free-network self-calibrating adjustment of the corrected target centres with the
//!    stepwise selection of distortion terms ([`super::selection`]);
//! 7. back to 4 with the new poses and intrinsics until the set of matches does not change
//!    between two iterations, or the camera moves by less than a tenth of its projection σ
//!    (capped, logged).

use nalgebra::{Vector2, Vector3};
use serde::Serialize;

use super::checks::{projection_difference_rotated, projection_uncertainty};
use super::matching::{MatchConfig, Matching, match_targets};
pub use super::neighbours::NeighbourDetections;
use super::refine::{Algorithm1, PairGeometry, RefineConfig, RefineError, algorithm1};
use super::selection::{
    ModelChoice, RollingShutterSetup, Selected, SelectionConfig, SelectionStep, adjust_terms,
    estimate_readout_time, select_terms,
};
use super::views::{FrameCamera, TargetObservation, observations};
use crate::adjust::{
    AdjustConfig, AdjustError, AdjustSummary, BrownModel, Loss, Observation, Problem,
    free_network_datum,
};
use crate::camera::rolling::Motion;
use crate::camera::{Intrinsics, Term};
use crate::geometry::Rigid3;
use crate::geometry::conic::Ellipse;
use crate::geometry::epipolar::fundamental_from_cameras;
use crate::io::colmap::Reconstruction;

/// How to calibrate.
#[derive(Clone, Debug)]
pub struct CalibrateConfig {
    /// Algorithm 1 settings.
    pub refine: RefineConfig,
    /// Algorithm 2/3 settings.
    pub matching: MatchConfig,
    /// Term selection.
    pub selection: SelectionConfig,
    /// Solver settings of the target adjustment.
    pub adjust: AdjustConfig,
    /// Run Algorithm 1 step 4 (feature adjustment) before matching.
    pub feature_adjustment: bool,
    /// Cap on matching/adjustment iterations, default 10 (simulated labs stop in 2–3; on real
    /// video the matches change by a few views at the gate for longer).
    pub max_iterations: usize,
    /// Targets need this many corrected views to enter the adjustment.
    pub min_views: usize,
    /// Fewer frames than this is an error.
    pub min_frames: usize,
    /// Fewer adjusted targets than this is an error.
    pub min_targets: usize,
    /// The loop also stops when the camera moved since the last iteration by less than this
    /// fraction of its worst projection σ (matches that still change by a view or two at the
    /// gate, or a term on the edge of selection, then move nothing that matters), default 0.1.
    pub camera_stable_ratio: f64,
    /// The rolling-shutter candidate of the term selection (issue 19): `None` leaves it out.
    /// It is tried when [`CalibrationInput::neighbours`] has the frames' neighbours in the
    /// video, or when [`ReadoutStart::hold`] gives the readout time. The selection tries it
    /// with the readout time held at [`ReadoutStart::readout_s`] (with one frame per instant
    /// only readout × velocity shows); once kept, the readout time is estimated from the
    /// neighbours, unless held.
    pub rolling_shutter: Option<ReadoutStart>,
}

/// A phone's readout time when nothing better is known (s): 4K30 video on phones reads out in
/// 15–33 ms.
pub const NOMINAL_READOUT_S: f64 = 0.025;

/// Where the readout time starts, and whether it is held.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReadoutStart {
    /// Readout time (s): the start of the estimate, or the value held.
    pub readout_s: f64,
    /// Hold it (a readout time known from elsewhere) instead of estimating it.
    pub hold: bool,
}

impl Default for ReadoutStart {
    fn default() -> Self {
        ReadoutStart {
            readout_s: NOMINAL_READOUT_S,
            hold: false,
        }
    }
}

impl Default for CalibrateConfig {
    fn default() -> Self {
        CalibrateConfig {
            refine: RefineConfig::default(),
            matching: MatchConfig::default(),
            selection: SelectionConfig::default(),
            adjust: AdjustConfig {
                function_tolerance: 1e-10,
                ..AdjustConfig::default()
            },
            feature_adjustment: true,
            max_iterations: 10,
            min_views: 3,
            min_frames: 10,
            min_targets: 20,
            camera_stable_ratio: 0.1,
            rolling_shutter: Some(ReadoutStart::default()),
        }
    }
}

/// Why a calibration failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CalibrateError {
    /// Algorithm 1 could not run.
    #[error(transparent)]
    Refine(#[from] RefineError),
    /// An adjustment could not run.
    #[error(transparent)]
    Adjust(#[from] AdjustError),
    /// Not enough data for a calibration.
    #[error("{what}: {found} found, at least {required} needed")]
    TooFew {
        /// What is missing.
        what: &'static str,
        /// How many there are.
        found: usize,
        /// How many are needed.
        required: usize,
    },
    /// The detections do not correspond to the model's frames.
    #[error("{0}")]
    Input(String),
}

/// One target observation of the final adjustment.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CalibrationObservation {
    /// Frame index (model order).
    pub frame: usize,
    /// Target index in [`Calibration::points`].
    pub target: usize,
    /// Observed pixel: Algorithm 3's centre in observed (distorted) pixels.
    pub uv: [f64; 2],
    /// Residual `measured − projected` (px).
    pub residual: [f64; 2],
}

/// One iteration of the loop.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LoopRecord {
    /// 1-based iteration.
    pub iteration: usize,
    /// Matched targets.
    pub tracks: usize,
    /// Their views.
    pub views: usize,
    /// Whether the matches differ from the previous iteration's.
    pub changed: bool,
    /// Targets and observations that entered the adjustment.
    pub adjusted_targets: usize,
    /// Observations that entered the adjustment.
    pub adjusted_observations: usize,
    /// σ0 of the adjustment (px).
    pub sigma0: f64,
    /// Terms selected.
    pub terms: Vec<Term>,
    /// What "one target, one track" changed in the matches.
    pub consolidation: crate::calibrate::tracks::Consolidation,
    /// Tracks dropped as not round in their plane (texture, not targets).
    pub not_round: usize,
    /// How far the camera moved since the previous iteration: the largest difference of the
    /// two models' projections over the frame after compensating a rotation (px).
    pub camera_change_px: Option<f64>,
    /// That change over the worst projection σ of this iteration's model.
    pub camera_change_ratio: Option<f64>,
    /// Whether the terms were held at an earlier choice instead of selected
    /// ([`TermAlternation`]).
    pub terms_held: bool,
}

/// The selection alternating between two sets of terms from one iteration to the next (a
/// term on the edge of the selection, tipped one way or the other by a view or two more at
/// the matching gate), and how the loop settled it: both sets adjusted on the same matches,
/// the lower BIC kept, and the terms held there for the rest of the loop.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TermAlternation {
    /// The iteration that selected a model it had selected two iterations before.
    pub iteration: usize,
    /// The two models.
    pub sets: [ModelChoice; 2],
    /// Their BIC on that iteration's matches.
    pub bic: [f64; 2],
    /// The model kept.
    pub kept: ModelChoice,
    /// How far apart the two models' projections are over the frame after compensating a
    /// rotation (px): what the choice does to the camera.
    pub camera_difference_px: f64,
    /// That difference over the kept model's worst projection σ.
    pub camera_difference_ratio: f64,
}

/// The frames' readout motion and the device's readout time, when the selection kept the
/// rolling-shutter model.
#[derive(Clone, Debug, PartialEq)]
pub struct RollingShutterEstimate {
    /// Readout time τ (s).
    pub readout_s: f64,
    /// Its σ (s); 0 when it was given rather than estimated.
    pub readout_std_s: f64,
    /// Whether τ was estimated (neighbouring video frames tie the motion to time).
    pub estimated: bool,
    /// Whether τ is the device's: estimated, or given by the user. `false` when it was held
    /// at [`NOMINAL_READOUT_S`] because frames without neighbours show only readout × rate:
    /// the motions then served the camera, and τ is no property of the device.
    pub determined: bool,
    /// Each adjusted frame's motion (order of [`Calibration::adjusted_frames`]; ν in the
    /// network's units per second).
    pub motions: Vec<Motion>,
}

/// A finished calibration.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The estimated intrinsics.
    pub intrinsics: Intrinsics,
    /// The terms estimated.
    pub terms: Vec<Term>,
    /// Standard deviations of the ten intrinsics (0 for fixed ones).
    pub std_dev: [f64; 10],
    /// Covariance of the ten intrinsics (σ0²·Q).
    pub covariance: nalgebra::DMatrix<f64>,
    /// A-posteriori σ0 (px).
    pub sigma0: f64,
    /// Redundancy of the final adjustment.
    pub redundancy: usize,
    /// RMS of the residuals per coordinate (px).
    pub residual_rms_px: f64,
    /// Frame names (model order).
    pub frame_names: Vec<String>,
    /// Poses (model order), on the inner-constraint datum: adjusted for the frames of
    /// [`Calibration::adjusted_frames`], Algorithm 1 step 4's (or the model's) for the others.
    pub cam_from_world: Vec<Rigid3>,
    /// The frames (model order) in the final adjustment; the others saw fewer than
    /// [`MIN_FRAME_OBSERVATIONS`] targets.
    pub adjusted_frames: Vec<usize>,
    /// Adjusted target centres.
    pub points: Vec<Vector3<f64>>,
    /// Covariance of each adjusted target (σ0²·Q, minimum trace over all targets), when the
    /// network is small enough for the dense inverse ([`MAX_COVARIANCE_UNKNOWNS`]).
    pub point_covariance: Option<Vec<nalgebra::Matrix3<f64>>>,
    /// Covariance of each adjusted frame's pose step `(δω, δt)` (σ0²·Q; order of
    /// [`Calibration::adjusted_frames`]).
    pub pose_covariance: Option<Vec<nalgebra::Matrix6<f64>>>,
    /// The final adjustment's observations with residuals.
    pub observations: Vec<CalibrationObservation>,
    /// The selection decisions of the final adjustment.
    pub selection: Vec<SelectionStep>,
    /// Radial residuals `(r, v_r)` of the c, u0, v0-only model (final iteration).
    pub radial_base: Vec<(f64, f64)>,
    /// The loop's iterations.
    pub iterations: Vec<LoopRecord>,
    /// Whether the loop converged: the matches stopped changing, or the camera stopped moving
    /// (by less than [`CalibrateConfig::camera_stable_ratio`] of its projection σ).
    pub converged: bool,
    /// Why the loop stopped, in words.
    pub stop_reason: String,
    /// The selection's alternation between two term sets, when the loop had to settle one.
    pub term_alternation: Option<TermAlternation>,
    /// The rolling-shutter model, when the selection kept it.
    pub rolling_shutter: Option<RollingShutterEstimate>,
    /// Algorithm 1 step 4's solver summary.
    pub feature_adjustment: Option<AdjustSummary>,
    /// The final adjustment's solver summary.
    pub summary: AdjustSummary,
    /// Warnings for the user (weak geometry, unconverged loop).
    pub warnings: Vec<String>,
    /// The SfM camera the loop started from.
    pub initial: Intrinsics,
    /// The jackknife over the frames that checked the covariance, when it ran (a video
    /// calibration whose neighbouring frames fixed the readout time; [`super::jackknife`]).
    pub frame_jackknife: Option<JackknifeCheck>,
}

/// What the jackknife over the frames ([`super::jackknife`]) found and did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct JackknifeCheck {
    /// Groups of frames (replicates).
    pub groups: usize,
    /// The factor the intrinsics' covariance was multiplied by (1 when the frames scatter
    /// no more than the adjustment's covariance says).
    pub variance_inflation: f64,
    /// The readout time's jackknife σ (s); the reported σ is the larger of it and the
    /// adjustment's.
    pub readout_std_s: f64,
}

/// The model frames' detections: `detections[k]` are the ellipses (observed pixels) of the
/// k-th registered image of `model` in image-id order.
#[derive(Clone, Debug)]
pub struct CalibrationInput<'a> {
    /// The SfM model.
    pub model: &'a Reconstruction,
    /// Per registered image (image-id order), its detected ellipses.
    pub detections: &'a [Vec<Ellipse>],
    /// Frame size (px).
    pub image_size: (u32, u32),
    /// Per registered image (image-id order), the detections in its neighbours in the video
    /// (`±1/fps`); empty when the frames are not from a video (or have no neighbours).
    pub neighbours: &'a [Vec<NeighbourDetections>],
}

/// A frame's detections linked to those of its neighbours: per neighbour, its time offset and,
/// per detection of the frame, the index of the same target's ellipse in the neighbour.
type NeighbourLinks = Vec<(f64, Vec<Option<usize>>)>;

/// Calibrates a device from an SfM model and the detections in its frames.
///
/// # Errors
/// [`CalibrateError`] for too few frames or targets, inconsistent input, or an adjustment that
/// cannot run.
pub fn calibrate(
    input: &CalibrationInput<'_>,
    config: &CalibrateConfig,
    log: &dyn Fn(&str),
) -> Result<Calibration, CalibrateError> {
    let n_frames = input.model.images.len();
    if n_frames < config.min_frames {
        return Err(CalibrateError::TooFew {
            what: "registered frames in the SfM model",
            found: n_frames,
            required: config.min_frames,
        });
    }
    if input.detections.len() != n_frames {
        return Err(CalibrateError::Input(format!(
            "{} detection lists for {n_frames} registered frames",
            input.detections.len()
        )));
    }
    if !input.neighbours.is_empty() && input.neighbours.len() != n_frames {
        return Err(CalibrateError::Input(format!(
            "{} neighbour lists for {n_frames} registered frames",
            input.neighbours.len()
        )));
    }
    let links = neighbour_links(input);
    let has_neighbours = links.iter().any(|l| !l.is_empty());
    let mut config = config.clone();
    // Without neighbours one frame per instant shows only readout × rate: the readout time is
    // held (the user's, or the nominal one) and the motions serve the camera alone. The rate
    // common to all frames, which trades with u0, p2, b1 and b2, is then what the same
    // significance and BIC tests weigh; on the simulated rolling-shutter labs without
    // neighbours the model took the camera from 2.6–10.6 px to within 0.6 px of the truth.
    let readout_nominal = config
        .rolling_shutter
        .is_some_and(|start| !start.hold && !has_neighbours);
    if let Some(start) = config.rolling_shutter {
        config.selection.rolling_shutter = Some(RollingShutterSetup {
            height_px: f64::from(input.image_size.1),
            readout_s: start.readout_s,
            estimate_readout: false,
            timed: has_neighbours,
        });
        if readout_nominal {
            log(&format!(
                "rolling shutter: no neighbouring video frames (FRAMES/frames.json) tie the frames' motions to time: tried with the readout time held at a nominal {:.0} ms; only readout × rate shows in a frame, so the readout time is not determined (give --readout-time if it is known, or extract the frames with `pipemeasure frames` to keep their neighbours) and only the camera benefits",
                1e3 * start.readout_s
            ));
        }
    }
    let config = &config;
    let estimate_readout = config.rolling_shutter.is_some_and(|r| !r.hold) && has_neighbours;
    if !input.neighbours.is_empty() {
        let linked: usize = links
            .iter()
            .flatten()
            .map(|(_, l)| l.iter().flatten().count())
            .sum();
        let total: usize = input.neighbours.iter().flatten().count();
        log(&format!(
            "rolling shutter: {total} neighbour frames in the video, {linked} of their detections linked to the frames'"
        ));
    }
    // Steps 1–2.
    let a1 = algorithm1(input.model, None, &config.refine)?;
    let initial = a1.frames[0].camera.intrinsics;
    log(&format!(
        "Algorithm 1: {} frames, {} overlapping pairs, {:.1} % of feature observations inliers, reprojection σ {:.2} px",
        a1.frames.len(),
        a1.pairs.len(),
        100.0 * a1.track_inlier_fraction(),
        a1.reprojection_sigma
    ));
    let mut cameras: Vec<FrameCamera> = a1.frames.iter().map(|f| f.camera).collect();
    let mut warnings = Vec::new();
    // Step 3.
    let feature_adjustment = if config.feature_adjustment {
        let (summary, intrinsics, poses) = adjust_feature_tracks(
            input.model,
            &a1,
            &cameras,
            &FEATURE_ADJUSTMENT_TERMS,
            &config.adjust,
        )?;
        log(&format!(
            "Algorithm 1 step 4: adjusted {} inlier feature observations, RMS {:.3} → {:.3} px; c {:.1}, u0 {:.1}, v0 {:.1}, k1 {:.4}, k2 {:.4}",
            summary.observations_used,
            (2.0 * summary.initial_cost / (2.0 * summary.observations_used as f64)).sqrt(),
            (2.0 * summary.final_cost / (2.0 * summary.observations_used as f64)).sqrt(),
            intrinsics.c,
            intrinsics.u0,
            intrinsics.v0,
            intrinsics.k1,
            intrinsics.k2
        ));
        for (cam, pose) in cameras.iter_mut().zip(poses) {
            *cam = FrameCamera {
                intrinsics,
                cam_from_world: pose,
            };
        }
        Some(summary)
    } else {
        None
    };
    let mut pairs: Vec<PairGeometry> = a1.pairs.clone();
    if config.feature_adjustment {
        refresh_pairs(&mut pairs, &cameras);
    }

    // The selection's settings: the rolling shutter is dropped from them when the neighbours
    // cannot determine the readout time.
    let mut selection = config.selection.clone();
    let frame_interval_s = input
        .neighbours
        .iter()
        .flatten()
        .map(|n| n.dt_s.abs())
        .fold(0.0, f64::max);
    let mut previous: Option<Vec<Vec<(usize, usize)>>> = None;
    let mut seen: Vec<Vec<Vec<(usize, usize)>>> = Vec::new();
    let mut iterations = Vec::new();
    let mut last: Option<(Selected, Vec<usize>)> = None;
    let mut converged = false;
    let mut stop_reason = String::new();
    // The model of each iteration, and the one held once the selection alternated.
    let mut term_history: Vec<ModelChoice> = Vec::new();
    let mut held: Option<ModelChoice> = None;
    let mut alternation: Option<TermAlternation> = None;
    // After the first iteration, an adjustment that fails (singular normal equations on
    // matches made with a camera that drifted) stops the loop with the last good adjustment,
    // warned, instead of losing the whole calibration.
    macro_rules! or_stop {
        ($iteration:expr, $result:expr) => {
            match $result {
                Ok(v) => v,
                Err(e) if last.is_some() => {
                    stop_reason = format!(
                        "iteration {} failed ({}); the previous iteration's adjustment is reported",
                        $iteration,
                        CalibrateError::from(e)
                    );
                    log(&stop_reason);
                    warnings.push(stop_reason.clone());
                    break;
                }
                Err(e) => return Err(e.into()),
            }
        };
    }
    for iteration in 1..=config.max_iterations {
        // Step 4.
        let obs: Vec<Vec<TargetObservation>> = cameras
            .iter()
            .zip(input.detections)
            .enumerate()
            .map(|(k, (cam, det))| observations(k, cam, det))
            .collect();
        // Step 5.
        let m = match_targets(
            &cameras,
            &obs,
            &pairs,
            input.image_size,
            a1.reprojection_sigma,
            &config.matching,
        );
        let signature = match_signature(&m);
        let changed = previous.as_ref() != Some(&signature);
        let cycle = changed && seen.contains(&signature);
        let views: usize = m.tracks.iter().map(|t| t.views.len()).sum();
        let record = LoopRecord {
            iteration,
            tracks: m.tracks.len(),
            views,
            changed,
            adjusted_targets: 0,
            adjusted_observations: 0,
            sigma0: f64::NAN,
            terms: Vec::new(),
            consolidation: m.consolidation,
            not_round: m.not_round,
            camera_change_px: None,
            camera_change_ratio: None,
            terms_held: false,
        };
        // Stop when the matches did not change, or came back to an earlier iteration's.
        if !changed || cycle {
            stop_reason = if changed {
                format!(
                    "the matches returned to an earlier iteration's ({} targets, {views} views): they alternate",
                    m.tracks.len()
                )
            } else {
                format!(
                    "the matches did not change ({} targets, {views} views)",
                    m.tracks.len()
                )
            };
            log(&format!("iteration {iteration}: {stop_reason}: done"));
            if changed {
                warnings.push(format!(
                    "iteration {iteration}: {stop_reason}; the last adjustment is reported"
                ));
            }
            iterations.push(record);
            converged = !changed;
            break;
        }
        seen.push(signature.clone());
        previous = Some(signature);
        // Step 6.
        let TargetProblem {
            problem,
            frames,
            dropped_frames,
            neighbour_observations,
        } = or_stop!(
            iteration,
            target_problem(&m, &cameras, &obs, input, &links, config)
        );
        if !dropped_frames.is_empty() {
            log(&format!(
                "iteration {iteration}: {} frame(s) left out of the adjustment, fewer than {MIN_FRAME_OBSERVATIONS} target observations: {}",
                dropped_frames.len(),
                dropped_frames
                    .iter()
                    .map(|&k| a1.frames[k].name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        let reference = problem.points.clone();
        let terms_held = held.is_some();
        let mut selected = match &held {
            Some(choice) => or_stop!(
                iteration,
                adjust_terms(&problem, choice, selection.rolling_shutter, &config.adjust)
            ),
            None => or_stop!(
                iteration,
                select_terms(&problem, &selection, &config.adjust, log)
            ),
        };
        if held.is_none()
            && let Some(settled) = settle_alternation(
                iteration,
                &selected,
                &term_history,
                &problem,
                input.image_size,
                config,
            )
            .unwrap_or_else(|e| {
                log(&format!(
                    "iteration {iteration}: the alternating models could not be compared ({e}); the selection's is kept"
                ));
                None
            })
        {
            let (kept, record) = settled;
            log(&format!(
                "iteration {iteration}: the selection alternates between {} (BIC {:.1}) and {} (BIC {:.1}); {} kept for the rest of the loop (lower BIC); the two cameras differ by {:.4} px at most ({:.3} × the projection σ)",
                record.sets[0],
                record.bic[0],
                record.sets[1],
                record.bic[1],
                record.kept,
                record.camera_difference_px,
                record.camera_difference_ratio
            ));
            if record.camera_difference_ratio > 1.0 {
                warnings.push(format!(
                    "the term selection is on the edge between {} and {}: the two cameras differ by {:.3} px ({:.2} × the reported projection σ); {} was kept (lower BIC)",
                    record.sets[0],
                    record.sets[1],
                    record.camera_difference_px,
                    record.camera_difference_ratio,
                    record.kept
                ));
            }
            held = Some(record.kept.clone());
            alternation = Some(record);
            selected = kept;
        }
        term_history.push(selected.choice());
        if estimate_readout
            && selected.rolling_shutter.is_some()
            && !neighbour_observations.is_empty()
        {
            let held_ms = 1e3 * selected.problem.global[BrownModel::READOUT];
            // The neighbours must tie the motions to time: a readout time outside the frame
            // interval, neighbours weighted next to nothing (their residuals 100 × the
            // frames'), or an adjustment that fails with them, leave the motions free, and
            // their drift along u0 + p2 runs the loop away (BoofCV's real video). The rolling
            // shutter is then left out for good.
            let accepted = match estimate_readout_time(
                selected,
                &neighbour_observations,
                &selection,
                &config.adjust,
                log,
            ) {
                Ok(e) => {
                    let readout_s = e.problem.global[BrownModel::READOUT];
                    let weight = e.neighbour_weight.unwrap_or(1.0);
                    log(&format!(
                        "iteration {iteration}: readout time from {} observations in the neighbouring video frames (weight {weight:.3} against the frames'): {:.2} ± {:.2} ms (held at {held_ms:.2} ms in the selection); σ0 {:.4} px",
                        neighbour_observations.len(),
                        1e3 * readout_s,
                        1e3 * e.readout_std_s.unwrap_or(0.0),
                        e.precision.sigma0
                    ));
                    if readout_s > 0.0
                        && readout_s <= frame_interval_s
                        && weight >= MIN_NEIGHBOUR_WEIGHT
                    {
                        Ok(e)
                    } else {
                        Err(format!(
                            "{:.2} ms for frames {:.2} ms apart, their weight {weight:.4} against the frames'",
                            1e3 * readout_s,
                            1e3 * frame_interval_s
                        ))
                    }
                }
                Err(e) => Err(format!("the adjustment with them failed: {e}")),
            };
            selected = match accepted {
                Ok(e) => e,
                Err(why) => {
                    let msg = format!(
                        "iteration {iteration}: the neighbouring video frames do not determine the readout time ({why}): the rolling shutter is left out and the terms selected again"
                    );
                    log(&msg);
                    warnings.push(msg);
                    selection.rolling_shutter = None;
                    held_choice_reset(&mut held);
                    or_stop!(
                        iteration,
                        select_terms(&problem, &selection, &config.adjust, log)
                    )
                }
            };
        }
        // A guard against a loop that runs away: when this iteration's matches fit several
        // times worse than the last adjustment's, they were made with a camera or motions
        // that had drifted (a rolling-shutter model whose motions the data did not fix, on
        // BoofCV's real video: σ0 0.035 → 6.3 px, then singular). The last good adjustment
        // is kept and reported.
        if let Some((prev, _)) = &last
            && selected.precision.sigma0 > DIVERGENCE_FACTOR * prev.precision.sigma0
        {
            stop_reason = format!(
                "iteration {iteration} diverged: σ0 {:.4} → {:.4} px with {} targets matched (more than {DIVERGENCE_FACTOR} × the last adjustment's); the previous iteration's adjustment is reported",
                prev.precision.sigma0,
                selected.precision.sigma0,
                m.tracks.len()
            );
            log(&stop_reason);
            warnings.push(stop_reason.clone());
            iterations.push(LoopRecord {
                adjusted_targets: selected.problem.points.len(),
                adjusted_observations: selected.precision.observations,
                sigma0: selected.precision.sigma0,
                terms: selected.terms.clone(),
                terms_held,
                ..record
            });
            break;
        }
        or_stop!(
            iteration,
            free_network_datum(&mut selected.problem, &reference)
        );
        let intrinsics = intrinsics_of(&selected.problem);
        // How far the camera moved since the last iteration, against its own uncertainty.
        let change = last.as_ref().map(|(prev, _)| {
            let moved = projection_difference_rotated(
                &intrinsics_of(&prev.problem),
                &intrinsics,
                input.image_size,
            )
            .map
            .max;
            let sigma = projection_uncertainty(
                &intrinsics,
                &intrinsic_covariance(&selected.precision),
                input.image_size,
            )
            .max;
            (moved, moved / sigma.max(f64::MIN_POSITIVE))
        });
        for cam in cameras.iter_mut() {
            cam.intrinsics = intrinsics;
        }
        for (&frame, pose) in frames.iter().zip(&selected.problem.cam_from_world) {
            cameras[frame].cam_from_world = *pose;
        }
        refresh_pairs(&mut pairs, &cameras);
        log(&format!(
            "iteration {iteration}: {} targets matched ({views} views; {} merged, {} views added by their points, {} not round in their plane), {} adjusted with {} observations; σ0 {:.4} px; terms {}{}",
            m.tracks.len(),
            m.consolidation.merged,
            m.consolidation.grown,
            m.not_round,
            selected.problem.points.len(),
            selected.precision.observations,
            selected.precision.sigma0,
            selected
                .terms
                .iter()
                .map(|t| t.name())
                .collect::<Vec<_>>()
                .join(", "),
            change.map_or(String::new(), |(px, ratio)| format!(
                "; the camera moved by {px:.4} px at most ({ratio:.3} × its projection σ)"
            ))
        ));
        iterations.push(LoopRecord {
            adjusted_targets: selected.problem.points.len(),
            adjusted_observations: selected.precision.observations,
            sigma0: selected.precision.sigma0,
            terms: selected.terms.clone(),
            camera_change_px: change.map(|c| c.0),
            camera_change_ratio: change.map(|c| c.1),
            terms_held,
            ..record
        });
        last = Some((selected, frames));
        if let Some((px, ratio)) = change
            && ratio < config.camera_stable_ratio
        {
            stop_reason = format!(
                "the matches changed ({} targets, {views} views) but the camera moved by {px:.4} px at most over the frame, {ratio:.3} × its projection σ (below {})",
                m.tracks.len(),
                config.camera_stable_ratio
            );
            log(&format!("iteration {iteration}: {stop_reason}: done"));
            converged = true;
            break;
        }
    }
    if !converged && stop_reason.is_empty() {
        stop_reason = format!(
            "the matches still changed after {} iterations{}",
            config.max_iterations,
            camera_moves(&iterations).map_or(String::new(), |(lo, hi)| format!(
                " (the camera moved by {lo:.2}–{hi:.2} × its projection σ per iteration)"
            ))
        );
        let msg = format!("{stop_reason}; the last adjustment is reported");
        log(&msg);
        warnings.push(msg);
    }
    let Some((mut selected, frames)) = last else {
        return Err(CalibrateError::Input("no iteration ran".into()));
    };
    let frame_jackknife = check_by_jackknife(&mut selected, input.image_size, &config.adjust, log);
    let mut cal = finish(
        selected,
        &frames,
        &cameras,
        &a1,
        iterations,
        (converged, stop_reason, alternation),
        feature_adjustment,
        warnings,
        initial,
        frame_jackknife,
    )?;
    if let Some(r) = cal.rolling_shutter.as_mut() {
        r.determined = r.estimated || !readout_nominal;
        if !r.determined {
            let msg = format!(
                "the rolling-shutter model was kept with the readout time held at a nominal {:.0} ms: the camera is corrected for the frames' motions, but the readout time is not determined and is left out of the profile",
                1e3 * r.readout_s
            );
            log(&msg);
            cal.warnings.push(msg);
        }
    }
    if let Some(msg) = residual_warning(&cal, has_neighbours) {
        log(&msg);
        cal.warnings.push(msg);
    }
    Ok(cal)
}

/// A sharp target's centre is located to about this (px): the simulated labs and BoofCV's real
/// dot-grid photos and video adjust to σ0 0.015–0.04 px.
pub const DETECTION_NOISE_PX: f64 = 0.05;

/// σ0 beyond this multiple of [`DETECTION_NOISE_PX`] means the model leaves out something the
/// images show (the simulated rolling-shutter labs without a motion model adjust to 0.16–0.45 px).
pub const SIGMA0_OVER_DETECTION_WARNING: f64 = 3.0;

/// A warning when the adjustment's σ0 is far above the detection noise, naming the likely
/// cause.
fn residual_warning(cal: &Calibration, has_neighbours: bool) -> Option<String> {
    let ratio = cal.sigma0 / DETECTION_NOISE_PX;
    if ratio <= SIGMA0_OVER_DETECTION_WARNING {
        return None;
    }
    let cause = match &cal.rolling_shutter {
        None if has_neighbours => {
            "the rolling shutter was refused although the frames have neighbours: check the frames' times in FRAMES/frames.json; else motion blur, wrong matches or a lens the model does not hold"
        }
        None => {
            "frames from a video without a rolling-shutter model (extract them with `pipemeasure frames` to keep their neighbours, or give --readout-time); else motion blur, wrong matches or a lens the model does not hold"
        }
        Some(_) => {
            "motion blur, a readout motion beyond the model's order, wrong matches, or a lens the model does not hold"
        }
    };
    Some(format!(
        "σ0 {:.3} px is {ratio:.0} × what sharp targets are located to ({DETECTION_NOISE_PX} px): the model leaves out something the images show; likely {cause}",
        cal.sigma0
    ))
}

/// Below this weight of the neighbouring video frames against the frames (their residuals
/// over 100 × the frames'), the neighbours do not fix the rolling-shutter motions. The
/// simulated video labs weight them 0.002–0.02 (tremor over 1/fps); BoofCV's real video, where
/// they did not fix the motions, below 5·10⁻⁵.
pub const MIN_NEIGHBOUR_WEIGHT: f64 = 1e-4;

/// A held model with a rolling shutter cannot be kept once the rolling shutter is left out.
fn held_choice_reset(held: &mut Option<ModelChoice>) {
    if held.as_ref().is_some_and(|c| c.rolling_shutter) {
        *held = None;
    }
}

/// An iteration whose σ0 exceeds this multiple of the previous adjustment's has diverged
/// ([`calibrate`] stops and reports the previous one).
pub const DIVERGENCE_FACTOR: f64 = 3.0;

/// The covariance of the ten intrinsics of an adjustment's precision (without the readout
/// time of a rolling-shutter model).
fn intrinsic_covariance(precision: &crate::adjust::Precision) -> nalgebra::DMatrix<f64> {
    precision
        .global_covariance
        .view((0, 0), (10, 10))
        .into_owned()
}

/// When this iteration's selection returned to the model of two iterations before after a
/// different one in between (an A, B, A pattern: a term on the edge of the selection), both
/// models are adjusted on this iteration's matches and the one with the lower BIC is returned
/// with the record of the choice; `None` otherwise.
fn settle_alternation(
    iteration: usize,
    selected: &Selected,
    history: &[ModelChoice],
    problem: &Problem<BrownModel>,
    image_size: (u32, u32),
    config: &CalibrateConfig,
) -> Result<Option<(Selected, TermAlternation)>, CalibrateError> {
    let [.., two_before, before] = history else {
        return Ok(None);
    };
    let now = selected.choice();
    if *two_before != now || *before == now {
        return Ok(None);
    }
    let other = adjust_terms(
        problem,
        before,
        config.selection.rolling_shutter,
        &config.adjust,
    )?;
    let bic = [selected.bic, other.bic];
    let (kept, dropped) = if other.bic < selected.bic {
        (other, selected.clone())
    } else {
        (selected.clone(), other)
    };
    let kept_intrinsics = intrinsics_of(&kept.problem);
    let difference = projection_difference_rotated(
        &kept_intrinsics,
        &intrinsics_of(&dropped.problem),
        image_size,
    )
    .map
    .max;
    let sigma = projection_uncertainty(
        &kept_intrinsics,
        &intrinsic_covariance(&kept.precision),
        image_size,
    )
    .max;
    let record = TermAlternation {
        iteration,
        sets: [now, before.clone()],
        bic,
        kept: kept.choice(),
        camera_difference_px: difference,
        camera_difference_ratio: difference / sigma.max(f64::MIN_POSITIVE),
    };
    Ok(Some((kept, record)))
}

#[allow(clippy::too_many_arguments)]
fn finish(
    selected: Selected,
    frames: &[usize],
    cameras: &[FrameCamera],
    a1: &Algorithm1,
    iterations: Vec<LoopRecord>,
    (converged, stop_reason, term_alternation): (bool, String, Option<TermAlternation>),
    feature_adjustment: Option<AdjustSummary>,
    mut warnings: Vec<String>,
    initial: Intrinsics,
    frame_jackknife: Option<JackknifeCheck>,
) -> Result<Calibration, CalibrateError> {
    let p = &selected.problem;
    let cov = intrinsic_covariance(&selected.precision);
    let mut std_dev = [0.0; 10];
    let global_std = selected.precision.global_std();
    std_dev.copy_from_slice(&global_std[..10]);
    let rolling_shutter = selected
        .rolling_shutter
        .map(|setup| RollingShutterEstimate {
            readout_s: p.global[BrownModel::READOUT],
            readout_std_s: selected.readout_std_s.unwrap_or(0.0),
            estimated: setup.estimate_readout,
            determined: true,
            motions: p.motions(),
        });
    let observations: Vec<CalibrationObservation> = p
        .observations
        .iter()
        .filter(|o| o.time_offset_s == 0.0)
        .filter_map(|o| {
            let r = -p.residual(o)?;
            Some(CalibrationObservation {
                frame: frames[o.camera],
                target: o.point,
                uv: [o.uv.x, o.uv.y],
                residual: [r.x, r.y],
            })
        })
        .collect();
    let ss: f64 = observations
        .iter()
        .map(|o| o.residual[0].powi(2) + o.residual[1].powi(2))
        .sum();
    let residual_rms_px = (ss / (2.0 * observations.len().max(1) as f64)).sqrt();
    let intrinsics = intrinsics_of(p);
    warnings.extend(geometry_warnings(&selected, p));
    let (point_covariance, pose_covariance) = network_covariance(p, &mut warnings);
    Ok(Calibration {
        intrinsics,
        terms: selected.terms.clone(),
        std_dev,
        covariance: cov,
        sigma0: selected.precision.sigma0,
        redundancy: selected.precision.redundancy,
        residual_rms_px,
        frame_names: a1.frames.iter().map(|f| f.name.clone()).collect(),
        cam_from_world: cameras.iter().map(|c| c.cam_from_world).collect(),
        adjusted_frames: frames.to_vec(),
        points: p.points.clone(),
        point_covariance,
        pose_covariance,
        observations,
        selection: selected.steps.clone(),
        radial_base: selected.radial_base.clone(),
        iterations,
        converged,
        stop_reason,
        term_alternation,
        rolling_shutter,
        feature_adjustment,
        summary: selected.summary,
        warnings,
        initial,
        frame_jackknife,
    })
}

/// Checks the final adjustment's covariance against the scatter of the frames by the grouped
/// jackknife ([`super::jackknife`]) and multiplies it by the variance inflation found: for a
/// rolling-shutter model whose readout time the neighbouring video frames fixed, where hand
/// tremor leaves one error per frame that the covariance counts as independent per target.
/// The readout time's σ becomes the larger of the adjustment's and the jackknife's. A
/// jackknife that cannot run (too few frames, a replicate that fails) leaves the covariance
/// as it is and says so in the log.
fn check_by_jackknife(
    selected: &mut Selected,
    image_size: (u32, u32),
    adjust: &AdjustConfig,
    log: &dyn Fn(&str),
) -> Option<JackknifeCheck> {
    selected.neighbour_weight?;
    selected.rolling_shutter.as_ref()?;
    let jackknife = match super::jackknife::frame_jackknife(&selected.problem, adjust) {
        Ok(j) => j,
        Err(e) => {
            log(&format!(
                "jackknife over the frames not run ({e}): the adjustment's covariance is reported"
            ));
            return None;
        }
    };
    let formal = intrinsic_covariance(&selected.precision);
    let inflation = super::jackknife::variance_inflation(
        &intrinsics_of(&selected.problem),
        &formal,
        &jackknife.covariance.view((0, 0), (10, 10)).into_owned(),
        image_size,
    );
    let readout_std_s = jackknife.std(BrownModel::READOUT);
    selected.precision.global_covariance *= inflation;
    let formal_readout = selected.readout_std_s.unwrap_or(0.0);
    selected.readout_std_s = Some(formal_readout.max(readout_std_s));
    log(&format!(
        "jackknife over {} groups of frames: the frames scatter the camera by {:.2} × the adjustment's projection σ (its covariance × {inflation:.2}), the readout time by {:.3} ms (the adjustment's {:.3} ms)",
        jackknife.groups,
        inflation.sqrt(),
        1e3 * readout_std_s,
        1e3 * formal_readout
    ));
    Some(JackknifeCheck {
        groups: jackknife.groups,
        variance_inflation: inflation,
        readout_std_s,
    })
}

/// Largest number of unknowns for which the targets' covariances are computed (a dense
/// inverse of the full normal matrix).
pub const MAX_COVARIANCE_UNKNOWNS: usize = 6000;

/// The targets' and poses' covariances of the final adjustment; `None` (with a warning) when
/// the network is too large or the precision cannot be computed.
#[allow(clippy::type_complexity)]
fn network_covariance(
    p: &Problem<BrownModel>,
    warnings: &mut Vec<String>,
) -> (
    Option<Vec<nalgebra::Matrix3<f64>>>,
    Option<Vec<nalgebra::Matrix6<f64>>>,
) {
    let unknowns = p.num_free_parameters();
    let request = crate::adjust::PrecisionRequest {
        poses: true,
        points: unknowns <= MAX_COVARIANCE_UNKNOWNS,
    };
    match crate::adjust::precision(p, request) {
        Ok(precision) => {
            let dg = p.global.len();
            let dc = (precision
                .reduced_covariance
                .as_ref()
                .map_or(0, nalgebra::DMatrix::nrows)
                .saturating_sub(dg))
                / p.cam_from_world.len().max(1);
            let poses = precision.reduced_covariance.as_ref().map(|c| {
                (0..p.cam_from_world.len())
                    .map(|j| c.fixed_view::<6, 6>(dg + j * dc, dg + j * dc).into_owned())
                    .collect()
            });
            if !request.points {
                warnings.push(format!(
                    "the network has {unknowns} unknowns: the targets' covariances were not computed (at most {MAX_COVARIANCE_UNKNOWNS})"
                ));
            }
            (precision.point_covariance, poses)
        }
        Err(e) => {
            warnings.push(format!(
                "the network's covariances could not be computed: {e}"
            ));
            (None, None)
        }
    }
}

/// Warnings about projective coupling: high correlations of c with the pose depth (a planar
/// field without roll diversity) show as |ρ(u0, v0 or c, …)| near 1 among the intrinsics.
fn geometry_warnings(selected: &Selected, p: &Problem<BrownModel>) -> Vec<String> {
    let corr = selected.precision.global_correlation();
    let mut out = Vec::new();
    // Radial terms correlate among themselves by construction (a polynomial basis); a
    // correlation of the principal distance, principal point or affinity with anything means
    // the network does not separate them.
    let geometric = |k: usize| {
        matches!(
            Term::ALL[k],
            Term::C | Term::U0 | Term::V0 | Term::B1 | Term::B2
        )
    };
    // Motions without neighbouring video frames leave a rate common to all frames free, and it
    // trades with the principal point, the decentring and the affinity terms.
    let motions_untimed = selected
        .rolling_shutter
        .is_some_and(|s| !s.estimate_readout);
    let traded_by_motions = |k: usize| {
        matches!(
            Term::ALL[k],
            Term::U0 | Term::V0 | Term::P1 | Term::P2 | Term::B1 | Term::B2
        )
    };
    for i in 0..10 {
        for j in 0..i {
            if (geometric(i) || geometric(j)) && corr[(i, j)].abs() > 0.98 {
                let why = if motions_untimed && traded_by_motions(i) && traded_by_motions(j) {
                    "the frames' motions, with no neighbouring video frames to tie them to time, leave a rate common to all frames that trades with both; their σ carries it (extract the frames with `pipemeasure frames` to keep their neighbours)"
                } else {
                    "the network does not separate them (vary the roll, portrait and landscape, and the depth)"
                };
                out.push(format!(
                    "correlation of {} and {} is {:.3}: {why}",
                    Term::ALL[j].name(),
                    Term::ALL[i].name(),
                    corr[(i, j)]
                ));
            }
        }
    }
    // Roll diversity: the frame is arbitrary (no known "up"), so the reference is the mean of
    // the cameras' image-down axes in the world; each camera's roll is the angle between its own
    // image-down axis and that mean seen in its image plane. Landscape-only (or portrait-only)
    // video keeps every roll within a few degrees; a mix puts them tens of degrees apart.
    let downs: Vec<nalgebra::Vector3<f64>> = p
        .cam_from_world
        .iter()
        .map(|pose| pose.rotation.inverse() * nalgebra::Vector3::y())
        .collect();
    let mean = downs.iter().sum::<nalgebra::Vector3<f64>>();
    if mean.norm() > 1e-9 {
        let largest = p
            .cam_from_world
            .iter()
            .map(|pose| {
                let v = pose.rotation * mean;
                v.x.atan2(v.y).abs()
            })
            .fold(0.0f64, f64::max);
        if largest < 0.3 {
            out.push(format!(
                "every frame has about the same roll (largest rotation about the viewing axis from the mean: {:.0}°): without portrait and landscape frames the principal point and the distortion couple with the poses; the profile may be wrong even where the residuals are small",
                largest.to_degrees()
            ));
        }
    }
    out
}

fn intrinsics_of(p: &Problem<BrownModel>) -> Intrinsics {
    let mut a = [0.0; 10];
    a.copy_from_slice(&p.global[..10]);
    Intrinsics::from_array(a)
}

/// F of every pair from the current cameras (after an adjustment the poses are the better
/// source); σ stays Algorithm 1's.
pub fn refresh_pairs(pairs: &mut [PairGeometry], cameras: &[FrameCamera]) {
    for pair in pairs {
        let (a, b) = (&cameras[pair.a], &cameras[pair.b]);
        if let Some(f) = fundamental_from_cameras(&a.p(), &a.centre(), &b.p()) {
            let n = f.norm();
            if n > 0.0 && n.is_finite() {
                pair.f = f / n;
            }
        }
    }
}

/// The least and the largest move of the camera between iterations, as a fraction of its
/// projection σ (`None` before a second adjustment): what a loop that ran out of iterations
/// still does (issue 18: a loop that does not settle reports how much the intrinsics move).
fn camera_moves(iterations: &[LoopRecord]) -> Option<(f64, f64)> {
    iterations
        .iter()
        .filter_map(|r| r.camera_change_ratio)
        .fold(None, |acc, r| match acc {
            None => Some((r, r)),
            Some((lo, hi)) => Some((f64::min(lo, r), f64::max(hi, r))),
        })
}

/// The matches as sorted lists of (frame, observation), for comparing iterations.
fn match_signature(m: &Matching) -> Vec<Vec<(usize, usize)>> {
    let mut s: Vec<Vec<(usize, usize)>> = m
        .tracks
        .iter()
        .map(|t| {
            let mut v: Vec<(usize, usize)> = t.views.iter().map(|v| (v.frame, v.obs)).collect();
            v.sort_unstable();
            v
        })
        .collect();
    s.sort();
    s
}

/// The target adjustment of one iteration, on the frames that observe enough targets.
struct TargetProblem {
    problem: Problem<BrownModel>,
    /// Per problem camera, its frame (model order).
    frames: Vec<usize>,
    /// Frames left out: too few target observations to fix their pose.
    dropped_frames: Vec<usize>,
    /// The views' targets seen in the frames' neighbours in the video, each at its time
    /// offset: they tie a rolling-shutter model's motions to time.
    neighbour_observations: Vec<Observation>,
}

/// The frames' detections linked to their neighbours' ([`super::neighbours::associate`]).
fn neighbour_links(input: &CalibrationInput<'_>) -> Vec<NeighbourLinks> {
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
                .map(|n| (n.dt_s, super::neighbours::associate(frame, &n.ellipses)))
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
fn target_problem(
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
    let index_of = super::refine::frame_index(&a1.frames);
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
        loss: Loss::Huber(3.0 * sigma_px.max(0.1)),
        ..*adjust
    };
    let summary = crate::adjust::bundle_adjust(problem, &adjust)?;
    free_network_datum(problem, &reference)?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiments::calibration::truth_target_problem;
    use crate::sim::lab::LabConfig;
    use crate::sim::simulate::{SimulateOptions, lab_geometry};

    /// A simulated p30 lab's true target centres with 0.02 px of noise (960×540, 40 frames).
    fn lab_problem() -> Problem<BrownModel> {
        let options = SimulateOptions {
            width: 960,
            height: 540,
            ..SimulateOptions::default()
        };
        let lab = LabConfig {
            frames: 40,
            ..LabConfig::default()
        };
        let (truth, _) = lab_geometry(&options, &lab).unwrap();
        truth_target_problem(&truth, 0.02, 3)
    }

    /// A loop that ran out of iterations reports the range of its camera's moves: the first
    /// iteration has none, the others' ratios bound it.
    #[test]
    fn camera_moves_spans_the_iterations_after_the_first() {
        let record = |iteration, ratio: Option<f64>| LoopRecord {
            iteration,
            tracks: 340,
            views: 11_700,
            changed: true,
            adjusted_targets: 338,
            adjusted_observations: 11_690,
            sigma0: 0.113,
            terms: vec![Term::C, Term::U0, Term::V0],
            consolidation: crate::calibrate::tracks::Consolidation::default(),
            not_round: 0,
            camera_change_px: ratio.map(|r| 0.68 * r),
            camera_change_ratio: ratio,
            terms_held: false,
        };
        assert_eq!(camera_moves(&[record(1, None)]), None);
        let loop_ = [
            record(1, None),
            record(2, Some(0.24)),
            record(3, Some(0.54)),
            record(4, Some(0.17)),
        ];
        assert_eq!(camera_moves(&loop_), Some((0.17, 0.54)));
    }

    /// The A, B, A pattern of selections is settled on the lower BIC of the two sets adjusted
    /// on the same matches, whichever came first; any other history leaves the selection alone.
    #[test]
    fn alternating_term_sets_are_settled_on_the_lower_bic() {
        let problem = lab_problem();
        let config = CalibrateConfig::default();
        let a = select_terms(&problem, &config.selection, &config.adjust, &|_| {}).unwrap();
        // The other model: the selection's without its last term.
        let mut b_choice = a.choice();
        let dropped = b_choice.terms.pop().unwrap();
        assert!(
            !matches!(dropped, Term::C | Term::U0 | Term::V0),
            "{:?}",
            a.terms
        );
        let b = adjust_terms(&problem, &b_choice, None, &config.adjust).unwrap();
        let size = (960, 540);
        for history in [
            vec![],
            vec![a.choice()],
            vec![a.choice(), a.choice()],
            vec![b_choice.clone(), a.choice()],
            vec![b_choice.clone(), b_choice.clone()],
        ] {
            let settled = settle_alternation(3, &a, &history, &problem, size, &config).unwrap();
            assert!(settled.is_none(), "{history:?}");
        }
        let (kept, record) = settle_alternation(
            3,
            &a,
            &[a.choice(), b_choice.clone()],
            &problem,
            size,
            &config,
        )
        .unwrap()
        .unwrap();
        assert_eq!(record.sets, [a.choice(), b_choice.clone()]);
        assert_eq!(record.bic, [a.bic, b.bic]);
        // The selection kept the term because it lowered the BIC: the full set stays.
        assert!(a.bic < b.bic, "{} vs {}", a.bic, b.bic);
        assert_eq!(record.kept, a.choice());
        assert_eq!(kept.terms, a.terms);
        assert!(record.camera_difference_px > 0.0 && record.camera_difference_ratio > 0.0);
        // Seen from the other side (B selected now, A before), the same model wins.
        let (kept, record) = settle_alternation(
            4,
            &b,
            &[b_choice.clone(), a.choice()],
            &problem,
            size,
            &config,
        )
        .unwrap()
        .unwrap();
        assert_eq!(record.kept, a.choice());
        assert_eq!(kept.terms, a.terms);
        assert_eq!(record.iteration, 4);
    }

    /// With the selected terms given, `adjust_terms` reproduces the selection's own model.
    #[test]
    fn adjusting_given_terms_reproduces_the_selection() {
        let problem = lab_problem();
        let config = AdjustConfig::default();
        let a = select_terms(&problem, &SelectionConfig::default(), &config, &|_| {}).unwrap();
        let again = adjust_terms(&problem, &a.choice(), None, &config).unwrap();
        assert_eq!(again.terms, a.terms);
        assert!(
            (again.bic - a.bic).abs() < 1e-6 * a.bic.abs(),
            "{} {}",
            again.bic,
            a.bic
        );
        for t in &a.terms {
            let (x, y) = (a.problem.global[t.index()], again.problem.global[t.index()]);
            let s = a.precision.global_std()[t.index()];
            assert!((x - y).abs() < 1e-3 * s, "{t}: {x} vs {y} ± {s}");
        }
        assert_eq!(again.radial_base.len(), a.radial_base.len());
    }
}
