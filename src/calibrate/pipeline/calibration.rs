//! The finished calibration ([`Calibration`]): the intrinsics with their covariance, the
//! loop's record and why it stopped ([`Termination`]), the rolling-shutter estimate, and how it
//! is built from the final adjustment: the jackknife over the frames that checks the
//! covariance ([`super::super::jackknife`]), the network's covariance, and the warnings on weak
//! geometry and on residuals far above the detection noise.

use nalgebra::Vector3;
use serde::Serialize;

use super::CalibrateError;
use crate::adjust::{AdjustConfig, AdjustSummary, BrownModel, Problem};
use crate::calibrate::refine::Algorithm1;
use crate::calibrate::selection::{ModelChoice, Selected, SelectionStep};
use crate::calibrate::views::FrameCamera;
use crate::camera::rolling::Motion;
use crate::camera::{Intrinsics, Term};
use crate::geometry::Rigid3;

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
    /// at [`super::NOMINAL_READOUT_S`] because frames without neighbours show only readout × rate:
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
    /// [`super::MIN_FRAME_OBSERVATIONS`] targets.
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
    /// Why the loop stopped ([`Calibration::converged`], [`Calibration::stop_reason`]).
    pub termination: Termination,
    /// The selection's alternation between two term sets, when the loop had to settle one.
    pub term_alternation: Option<TermAlternation>,
    /// The rolling-shutter model, when the selection kept it.
    pub rolling_shutter: Option<RollingShutterEstimate>,
    /// Algorithm 1 step 4's solver summary.
    pub feature_adjustment: Option<AdjustSummary>,
    /// The final adjustment's solver summary.
    pub summary: AdjustSummary,
    /// Warnings for the user (weak geometry, unconverged loop; after
    /// [`crate::calibrate::calibrate_device`], its checks' too: a distortion that folds back,
    /// halves that disagree).
    pub warnings: Vec<String>,
    /// The SfM camera the loop started from.
    pub initial: Intrinsics,
    /// The jackknife over the frames that checked the covariance, when it ran (a video
    /// calibration whose neighbouring frames fixed the readout time; [`crate::calibrate::jackknife`]).
    pub frame_jackknife: Option<JackknifeCheck>,
}

impl Calibration {
    /// Whether the loop converged: the matches stopped changing, or the camera stopped moving
    /// (by less than [`super::CalibrateConfig::camera_stable_ratio`] of its projection σ).
    #[must_use]
    pub fn converged(&self) -> bool {
        self.termination.converged()
    }

    /// Why the loop stopped, in words.
    #[must_use]
    pub fn stop_reason(&self) -> String {
        self.termination.to_string()
    }
}

/// How the calibration loop ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Termination {
    /// The matches did not change between two iterations: converged.
    MatchesStable {
        /// The iteration that found them unchanged.
        iteration: usize,
        /// Matched targets.
        targets: usize,
        /// Their views.
        views: usize,
    },
    /// The matches came back to an earlier iteration's: they alternate (a view or two at the
    /// gate); the last adjustment is reported.
    MatchesAlternate {
        /// The iteration that found them again.
        iteration: usize,
        /// Matched targets.
        targets: usize,
        /// Their views.
        views: usize,
    },
    /// The matches changed, but the camera moved by less than
    /// [`super::CalibrateConfig::camera_stable_ratio`] of its projection σ: converged.
    CameraSettled {
        /// The iteration.
        iteration: usize,
        /// Matched targets.
        targets: usize,
        /// Their views.
        views: usize,
        /// The largest move of the camera's projections over the frame (px).
        moved_px: f64,
        /// That move over the worst projection σ.
        ratio: f64,
        /// The ratio below which the camera counts as settled.
        threshold: f64,
    },
    /// The iterations ran out while the matches still changed; the last adjustment is
    /// reported.
    IterationCap {
        /// The cap ([`super::CalibrateConfig::max_iterations`]).
        iterations: usize,
        /// The least and largest move of the camera per iteration, over its projection σ.
        camera_moves: Option<(f64, f64)>,
    },
    /// An iteration's adjustment could not run; the previous iteration's is reported.
    AdjustmentFailed {
        /// The iteration.
        iteration: usize,
        /// Why, in words.
        cause: String,
    },
    /// An iteration's σ0 exceeded [`super::DIVERGENCE_FACTOR`] × the previous adjustment's;
    /// the previous one is reported.
    Diverged {
        /// The iteration.
        iteration: usize,
        /// The previous adjustment's σ0 (px).
        sigma0_before: f64,
        /// This iteration's σ0 (px).
        sigma0_after: f64,
        /// Targets matched in this iteration.
        targets: usize,
    },
}

impl Termination {
    /// Whether the loop converged (the matches or the camera settled).
    #[must_use]
    pub fn converged(&self) -> bool {
        matches!(
            self,
            Termination::MatchesStable { .. } | Termination::CameraSettled { .. }
        )
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Termination::MatchesStable { targets, views, .. } => write!(
                f,
                "the matches did not change ({targets} targets, {views} views)"
            ),
            Termination::MatchesAlternate { targets, views, .. } => write!(
                f,
                "the matches returned to an earlier iteration's ({targets} targets, {views} views): they alternate"
            ),
            Termination::CameraSettled {
                targets,
                views,
                moved_px,
                ratio,
                threshold,
                ..
            } => write!(
                f,
                "the matches changed ({targets} targets, {views} views) but the camera moved by {moved_px:.4} px at most over the frame, {ratio:.3} × its projection σ (below {threshold})"
            ),
            Termination::IterationCap {
                iterations,
                camera_moves,
            } => {
                write!(f, "the matches still changed after {iterations} iterations")?;
                if let Some((lo, hi)) = camera_moves {
                    write!(
                        f,
                        " (the camera moved by {lo:.2}–{hi:.2} × its projection σ per iteration)"
                    )?;
                }
                Ok(())
            }
            Termination::AdjustmentFailed { iteration, cause } => write!(
                f,
                "iteration {iteration} failed ({cause}); the previous iteration's adjustment is reported"
            ),
            Termination::Diverged {
                iteration,
                sigma0_before,
                sigma0_after,
                targets,
            } => write!(
                f,
                "iteration {iteration} diverged: σ0 {sigma0_before:.4} → {sigma0_after:.4} px with {targets} targets matched (more than {} × the last adjustment's); the previous iteration's adjustment is reported",
                super::DIVERGENCE_FACTOR
            ),
        }
    }
}

/// What the jackknife over the frames ([`crate::calibrate::jackknife`]) found and did.
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

/// A sharp target's centre is located to about this (px): the simulated labs and BoofCV's real
/// dot-grid photos and video adjust to σ0 0.015–0.04 px.
pub const DETECTION_NOISE_PX: f64 = 0.05;

/// σ0 beyond this multiple of [`DETECTION_NOISE_PX`] means the model leaves out something the
/// images show (the simulated rolling-shutter labs without a motion model adjust to 0.16–0.45 px).
pub const SIGMA0_OVER_DETECTION_WARNING: f64 = 3.0;

/// A warning when the adjustment's σ0 is far above the detection noise, naming the likely
/// cause.
pub(super) fn residual_warning(cal: &Calibration, has_neighbours: bool) -> Option<String> {
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

/// The covariance of the ten intrinsics of an adjustment's precision (without the readout
/// time of a rolling-shutter model).
pub(super) fn intrinsic_covariance(precision: &crate::adjust::Precision) -> nalgebra::DMatrix<f64> {
    precision
        .global_covariance
        .view((0, 0), (10, 10))
        .into_owned()
}

#[allow(clippy::too_many_arguments)]
pub(super) fn finish(
    selected: Selected,
    frames: &[usize],
    cameras: &[FrameCamera],
    a1: &Algorithm1,
    iterations: Vec<LoopRecord>,
    (termination, term_alternation): (Termination, Option<TermAlternation>),
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
        termination,
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
pub(super) fn check_by_jackknife(
    selected: &mut Selected,
    image_size: (u32, u32),
    adjust: &AdjustConfig,
    log: &dyn Fn(&str),
) -> Option<JackknifeCheck> {
    selected.neighbour_weight?;
    selected.rolling_shutter.as_ref()?;
    let jackknife = match crate::calibrate::jackknife::frame_jackknife(&selected.problem, adjust) {
        Ok(j) => j,
        Err(e) => {
            log(&format!(
                "jackknife over the frames not run ({e}): the adjustment's covariance is reported"
            ));
            return None;
        }
    };
    let formal = intrinsic_covariance(&selected.precision);
    let inflation = crate::calibrate::jackknife::variance_inflation(
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

/// A correlation of the principal distance, principal point or affinity with another term
/// beyond this is warned about: the network does not separate the two.
const WARN_CORRELATION: f64 = 0.98;
/// Largest roll of any frame from the mean (rad, 17°) below which the frames count as all
/// one roll (landscape-only or portrait-only video keeps every roll within a few degrees).
const SAME_ROLL_RAD: f64 = 0.3;

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
            if (geometric(i) || geometric(j)) && corr[(i, j)].abs() > WARN_CORRELATION {
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
        if largest < SAME_ROLL_RAD {
            out.push(format!(
                "every frame has about the same roll (largest rotation about the viewing axis from the mean: {:.0}°): without portrait and landscape frames the principal point and the distortion couple with the poses; the profile may be wrong even where the residuals are small",
                largest.to_degrees()
            ));
        }
    }
    out
}

/// The ten intrinsics of an adjustment (the readout time of a rolling-shutter model left out).
pub(super) fn intrinsics_of(p: &Problem<BrownModel>) -> Intrinsics {
    let mut a = [0.0; 10];
    a.copy_from_slice(&p.global[..10]);
    Intrinsics::from_array(a)
}
