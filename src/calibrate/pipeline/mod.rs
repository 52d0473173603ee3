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

mod calibration;
mod iterate;
mod problems;

pub use calibration::{
    Calibration, CalibrationObservation, DETECTION_NOISE_PX, JackknifeCheck, LoopRecord,
    MAX_COVARIANCE_UNKNOWNS, RollingShutterEstimate, SIGMA0_OVER_DETECTION_WARNING,
    TermAlternation, Termination,
};
pub(crate) use problems::adjust_tracks_free_network;
pub use problems::{
    FEATURE_ADJUSTMENT_TERMS, MIN_FRAME_OBSERVATIONS, adjust_feature_tracks, feature_problem,
};

use super::checks::{projection_difference_rotated, projection_uncertainty};
use super::matching::{MatchConfig, Matching};
pub use super::neighbours::NeighbourDetections;
use super::refine::{Algorithm1, PairGeometry, RefineConfig, RefineError, algorithm1};
use super::selection::{ModelChoice, RollingShutterSetup, Selected, SelectionConfig, adjust_terms};
use super::views::FrameCamera;
use crate::adjust::{AdjustConfig, AdjustError, AdjustSummary, BrownModel, Problem};
use crate::camera::Intrinsics;
use crate::geometry::conic::Ellipse;
use crate::geometry::epipolar::fundamental_from_cameras;
use crate::io::colmap::Reconstruction;
use calibration::{
    check_by_jackknife, finish, intrinsic_covariance, intrinsics_of, residual_warning,
};
use iterate::{Loop, LoopInput, LoopOutcome};
use problems::neighbour_links;

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
    /// The rolling-shutter candidate of the term selection: `None` leaves it out.
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
    /// The calibration of one half of the frames for the cross-validation
    /// ([`super::device`]).
    #[error("cross-validation half {half}: {source}")]
    CrossValidation {
        /// 1 (odd frames) or 2 (even frames).
        half: usize,
        /// Why it failed.
        #[source]
        source: Box<CalibrateError>,
    },
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
    check_input(input, config)?;
    let links = neighbour_links(input);
    let has_neighbours = links.iter().any(|l| !l.is_empty());
    let (config, readout_nominal) =
        with_rolling_shutter(config, input.image_size, has_neighbours, log);
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
    let start = start_from_features(input, config, log)?;
    let frame_interval_s = input
        .neighbours
        .iter()
        .flatten()
        .map(|n| n.dt_s.abs())
        .fold(0.0, f64::max);
    let outcome = Loop::new(
        LoopInput {
            input,
            config,
            links: &links,
            a1: &start.a1,
            estimate_readout,
            frame_interval_s,
            log,
        },
        start.cameras,
        start.pairs,
    )
    .run()?;
    let LoopOutcome {
        termination,
        cameras,
        iterations,
        last,
        alternation,
        warnings,
    } = outcome;
    let Some((mut selected, frames)) = last else {
        return Err(CalibrateError::Input("no iteration ran".into()));
    };
    let frame_jackknife = check_by_jackknife(&mut selected, input.image_size, &config.adjust, log);
    let mut cal = finish(
        selected,
        &frames,
        &cameras,
        &start.a1,
        iterations,
        (termination, alternation),
        start.feature_adjustment,
        warnings,
        start.initial,
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

/// The input's frames, detections and neighbours agree, and there are enough frames.
fn check_input(
    input: &CalibrationInput<'_>,
    config: &CalibrateConfig,
) -> Result<(), CalibrateError> {
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
    Ok(())
}

/// The configuration with the term selection's rolling-shutter candidate set up for these
/// frames, and whether its readout time is only a nominal one (no neighbours to time the
/// motions, none given).
fn with_rolling_shutter(
    config: &CalibrateConfig,
    image_size: (u32, u32),
    has_neighbours: bool,
    log: &dyn Fn(&str),
) -> (CalibrateConfig, bool) {
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
            height_px: f64::from(image_size.1),
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
    (config, readout_nominal)
}

/// Where the loop starts: Algorithm 1 (steps 1–2) and, when configured, its step 4, the
/// adjustment of the inlier feature tracks that gives the poses and a first camera.
struct Start {
    a1: Algorithm1,
    /// Algorithm 1's camera, before any adjustment.
    initial: Intrinsics,
    cameras: Vec<FrameCamera>,
    pairs: Vec<PairGeometry>,
    feature_adjustment: Option<AdjustSummary>,
}

/// Steps 1–3 of the loop ([`Start`]).
fn start_from_features(
    input: &CalibrationInput<'_>,
    config: &CalibrateConfig,
    log: &dyn Fn(&str),
) -> Result<Start, CalibrateError> {
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
    Ok(Start {
        a1,
        initial,
        cameras,
        pairs,
        feature_adjustment,
    })
}

/// Below this weight of the neighbouring video frames against the frames (their residuals
/// over 100 × the frames'), the neighbours do not fix the rolling-shutter motions. The
/// simulated video labs weight them 0.002–0.02 (tremor over 1/fps); BoofCV's real video, where
/// they did not fix the motions, below 5·10⁻⁵.
pub const MIN_NEIGHBOUR_WEIGHT: f64 = 1e-4;

/// An iteration whose σ0 exceeds this multiple of the previous adjustment's has diverged
/// ([`calibrate`] stops and reports the previous one).
pub const DIVERGENCE_FACTOR: f64 = 3.0;

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
/// still does (a loop that does not settle reports how much the intrinsics move).
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::selection::select_terms;
    use crate::camera::Term;
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
