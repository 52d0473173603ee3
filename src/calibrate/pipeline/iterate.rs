//! Steps 4–7 of the calibration loop, repeated until they settle: the detections undistorted
//! with the current camera, matched (Algorithms 2–3), adjusted with the stepwise selection of
//! terms, the cameras and pairs updated; each iteration either continues or ends the loop
//! with its [`Termination`].

use super::calibration::{LoopRecord, TermAlternation, Termination, intrinsic_covariance};
use super::problems::{TargetProblem, target_problem};
use super::{
    CalibrateConfig, CalibrateError, CalibrationInput, DIVERGENCE_FACTOR, MIN_FRAME_OBSERVATIONS,
    MIN_NEIGHBOUR_WEIGHT, NeighbourLinks, camera_moves, intrinsics_of, match_signature,
    refresh_pairs, settle_alternation,
};
use crate::adjust::{BrownModel, free_network_datum};
use crate::calibrate::checks::{projection_difference_rotated, projection_uncertainty};
use crate::calibrate::matching::{Matching, match_targets};
use crate::calibrate::refine::{Algorithm1, PairGeometry};
use crate::calibrate::selection::{
    ModelChoice, Selected, SelectionConfig, adjust_terms, estimate_readout_time, select_terms,
};
use crate::calibrate::views::{FrameCamera, TargetObservation, observations};

/// The matches of one iteration as sorted lists of (frame, observation).
type Signature = Vec<Vec<(usize, usize)>>;

/// What the loop reads and never changes.
pub(super) struct LoopInput<'a> {
    pub input: &'a CalibrationInput<'a>,
    pub config: &'a CalibrateConfig,
    pub links: &'a [NeighbourLinks],
    pub a1: &'a Algorithm1,
    /// Estimate the readout time from the neighbouring video frames once the rolling shutter
    /// is kept.
    pub estimate_readout: bool,
    /// The largest time between a frame and its neighbours (s).
    pub frame_interval_s: f64,
    pub log: &'a dyn Fn(&str),
}

/// What the loop leaves when it ends ([`Loop::run`]).
pub(super) struct LoopOutcome {
    /// How it ended.
    pub termination: Termination,
    /// The frames' cameras: the last intrinsics and adjusted poses.
    pub cameras: Vec<FrameCamera>,
    /// One record per iteration.
    pub iterations: Vec<LoopRecord>,
    /// The last good adjustment and its frames (model order).
    pub last: Option<(Selected, Vec<usize>)>,
    /// The alternation of the term selection, when it alternated.
    pub alternation: Option<TermAlternation>,
    /// What the report must say.
    pub warnings: Vec<String>,
}

/// The loop's state between iterations.
pub(super) struct Loop<'a> {
    fixed: LoopInput<'a>,
    /// The frames' cameras: the current intrinsics and the last adjusted poses.
    cameras: Vec<FrameCamera>,
    pairs: Vec<PairGeometry>,
    /// The selection's settings: the rolling shutter is dropped from them when the neighbours
    /// cannot determine the readout time.
    selection: SelectionConfig,
    previous: Option<Signature>,
    seen: Vec<Signature>,
    iterations: Vec<LoopRecord>,
    /// The last good adjustment and its frames (model order).
    last: Option<(Selected, Vec<usize>)>,
    /// The model of each iteration, and the one held once the selection alternated.
    term_history: Vec<ModelChoice>,
    held: Option<ModelChoice>,
    alternation: Option<TermAlternation>,
    warnings: Vec<String>,
}

impl<'a> Loop<'a> {
    pub(super) fn new(
        fixed: LoopInput<'a>,
        cameras: Vec<FrameCamera>,
        pairs: Vec<PairGeometry>,
    ) -> Self {
        let selection = fixed.config.selection.clone();
        Loop {
            fixed,
            cameras,
            pairs,
            selection,
            previous: None,
            seen: Vec::new(),
            iterations: Vec::new(),
            last: None,
            term_history: Vec::new(),
            held: None,
            alternation: None,
            warnings: Vec::new(),
        }
    }

    /// Runs iterations until one ends the loop or the cap is reached; logs and warns why it
    /// stopped, and returns what it leaves.
    pub(super) fn run(mut self) -> Result<LoopOutcome, CalibrateError> {
        let mut termination = None;
        for iteration in 1..=self.fixed.config.max_iterations {
            if let Some(t) = self.iterate(iteration)? {
                termination = Some(t);
                break;
            }
        }
        let termination = termination.unwrap_or_else(|| Termination::IterationCap {
            iterations: self.fixed.config.max_iterations,
            camera_moves: camera_moves(&self.iterations),
        });
        self.announce(&termination);
        Ok(LoopOutcome {
            termination,
            cameras: self.cameras,
            iterations: self.iterations,
            last: self.last,
            alternation: self.alternation,
            warnings: self.warnings,
        })
    }

    /// The log line and the warning of each way the loop ends.
    fn announce(&mut self, t: &Termination) {
        let log = self.fixed.log;
        match t {
            Termination::MatchesStable { iteration, .. }
            | Termination::CameraSettled { iteration, .. } => {
                log(&format!("iteration {iteration}: {t}: done"));
            }
            Termination::MatchesAlternate { iteration, .. } => {
                log(&format!("iteration {iteration}: {t}: done"));
                self.warnings.push(format!(
                    "iteration {iteration}: {t}; the last adjustment is reported"
                ));
            }
            Termination::AdjustmentFailed { .. } | Termination::Diverged { .. } => {
                log(&t.to_string());
                self.warnings.push(t.to_string());
            }
            Termination::IterationCap { .. } => {
                let msg = format!("{t}; the last adjustment is reported");
                log(&msg);
                self.warnings.push(msg);
            }
        }
    }

    /// After the first iteration, an adjustment that fails (singular normal equations on
    /// matches made with a camera that drifted) ends the loop with the last good adjustment,
    /// warned, instead of losing the whole calibration; in the first it is the calibration's
    /// error.
    fn failed(
        &self,
        iteration: usize,
        e: impl Into<CalibrateError>,
    ) -> Result<Option<Termination>, CalibrateError> {
        let e = e.into();
        if self.last.is_some() {
            Ok(Some(Termination::AdjustmentFailed {
                iteration,
                cause: e.to_string(),
            }))
        } else {
            Err(e)
        }
    }

    /// One iteration of steps 4–7; `Some` when it ends the loop.
    fn iterate(&mut self, iteration: usize) -> Result<Option<Termination>, CalibrateError> {
        let LoopInput {
            input,
            config,
            links,
            a1,
            log,
            ..
        } = self.fixed;
        let (obs, m) = self.match_frames();
        let signature = match_signature(&m);
        let changed = self.previous.as_ref() != Some(&signature);
        let cycle = changed && self.seen.contains(&signature);
        let views: usize = m.tracks.iter().map(|t| t.views.len()).sum();
        let targets = m.tracks.len();
        let record = LoopRecord {
            iteration,
            tracks: targets,
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
            self.iterations.push(record);
            return Ok(Some(if changed {
                Termination::MatchesAlternate {
                    iteration,
                    targets,
                    views,
                }
            } else {
                Termination::MatchesStable {
                    iteration,
                    targets,
                    views,
                }
            }));
        }
        self.seen.push(signature.clone());
        self.previous = Some(signature);
        // Step 6.
        let TargetProblem {
            problem,
            frames,
            dropped_frames,
            neighbour_observations,
        } = match target_problem(&m, &self.cameras, &obs, input, links, config) {
            Ok(p) => p,
            Err(e) => return self.failed(iteration, e),
        };
        if !dropped_frames.is_empty() {
            log(&dropped_line(iteration, &dropped_frames, a1));
        }
        let reference = problem.points.clone();
        let terms_held = self.held.is_some();
        let chosen = match &self.held {
            Some(choice) => adjust_terms(
                &problem,
                choice,
                self.selection.rolling_shutter,
                &config.adjust,
            ),
            None => select_terms(&problem, &self.selection, &config.adjust, log),
        };
        let mut selected = match chosen {
            Ok(s) => s,
            Err(e) => return self.failed(iteration, e),
        };
        if self.held.is_none() {
            selected = self.settle(iteration, selected, &problem);
        }
        self.term_history.push(selected.choice());
        if self.fixed.estimate_readout
            && selected.rolling_shutter.is_some()
            && !neighbour_observations.is_empty()
        {
            selected = match self.with_readout_time(iteration, selected, &neighbour_observations) {
                Some(s) => s,
                None => match select_terms(&problem, &self.selection, &config.adjust, log) {
                    Ok(s) => s,
                    Err(e) => return self.failed(iteration, e),
                },
            };
        }
        // A guard against a loop that runs away: when this iteration's matches fit several
        // times worse than the last adjustment's, they were made with a camera or motions
        // that had drifted (a rolling-shutter model whose motions the data did not fix, on
        // BoofCV's real video: σ0 0.035 → 6.3 px, then singular). The last good adjustment
        // is kept and reported.
        if let Some((prev, _)) = &self.last
            && selected.precision.sigma0 > DIVERGENCE_FACTOR * prev.precision.sigma0
        {
            let sigma0_before = prev.precision.sigma0;
            self.iterations.push(LoopRecord {
                adjusted_targets: selected.problem.points.len(),
                adjusted_observations: selected.precision.observations,
                sigma0: selected.precision.sigma0,
                terms: selected.terms.clone(),
                terms_held,
                ..record
            });
            return Ok(Some(Termination::Diverged {
                iteration,
                sigma0_before,
                sigma0_after: selected.precision.sigma0,
                targets,
            }));
        }
        if let Err(e) = free_network_datum(&mut selected.problem, &reference) {
            return self.failed(iteration, e);
        }
        let change = self.adopt(&selected, &frames);
        log(&iteration_line(iteration, &m, views, &selected, change));
        self.iterations.push(LoopRecord {
            adjusted_targets: selected.problem.points.len(),
            adjusted_observations: selected.precision.observations,
            sigma0: selected.precision.sigma0,
            terms: selected.terms.clone(),
            camera_change_px: change.map(|c| c.0),
            camera_change_ratio: change.map(|c| c.1),
            terms_held,
            ..record
        });
        self.last = Some((selected, frames));
        Ok(change.and_then(|(moved_px, ratio)| {
            (ratio < config.camera_stable_ratio).then_some(Termination::CameraSettled {
                iteration,
                targets,
                views,
                moved_px,
                ratio,
                threshold: config.camera_stable_ratio,
            })
        }))
    }

    /// Steps 4–5: each frame's detections undistorted with its current camera, and matched
    /// (Algorithms 2–3).
    fn match_frames(&self) -> (Vec<Vec<TargetObservation>>, Matching) {
        let LoopInput {
            input, config, a1, ..
        } = self.fixed;
        let obs: Vec<Vec<TargetObservation>> = self
            .cameras
            .iter()
            .zip(input.detections)
            .enumerate()
            .map(|(k, (cam, det))| observations(k, cam, det))
            .collect();
        let m = match_targets(
            &self.cameras,
            &obs,
            &self.pairs,
            input.image_size,
            a1.reprojection_sigma,
            &config.matching,
        );
        (obs, m)
    }

    /// Takes the adjustment's camera and poses for the next iteration and refreshes the
    /// pairs' geometry; returns how far the camera moved since the last iteration, in pixels
    /// and against its own projection σ (`None` in the first).
    fn adopt(&mut self, selected: &Selected, frames: &[usize]) -> Option<(f64, f64)> {
        let size = self.fixed.input.image_size;
        let intrinsics = intrinsics_of(&selected.problem);
        let change = self.last.as_ref().map(|(prev, _)| {
            let moved =
                projection_difference_rotated(&intrinsics_of(&prev.problem), &intrinsics, size)
                    .map
                    .max;
            let sigma = projection_uncertainty(
                &intrinsics,
                &intrinsic_covariance(&selected.precision),
                size,
            )
            .max;
            (moved, moved / sigma.max(f64::MIN_POSITIVE))
        });
        for cam in self.cameras.iter_mut() {
            cam.intrinsics = intrinsics;
        }
        for (&frame, pose) in frames.iter().zip(&selected.problem.cam_from_world) {
            self.cameras[frame].cam_from_world = *pose;
        }
        refresh_pairs(&mut self.pairs, &self.cameras);
        change
    }

    /// The selection alternating between two models ([`settle_alternation`]): the one with
    /// the lower BIC is kept and held for the rest of the loop; the selection's own model when
    /// there is no alternation or the two cannot be compared.
    fn settle(
        &mut self,
        iteration: usize,
        selected: Selected,
        problem: &crate::adjust::Problem<BrownModel>,
    ) -> Selected {
        let log = self.fixed.log;
        let settled = settle_alternation(
            iteration,
            &selected,
            &self.term_history,
            problem,
            self.fixed.input.image_size,
            self.fixed.config,
        )
        .unwrap_or_else(|e| {
            log(&format!(
                "iteration {iteration}: the alternating models could not be compared ({e}); the selection's is kept"
            ));
            None
        });
        let Some((kept, record)) = settled else {
            return selected;
        };
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
            self.warnings.push(format!(
                "the term selection is on the edge between {} and {}: the two cameras differ by {:.3} px ({:.2} × the reported projection σ); {} was kept (lower BIC)",
                record.sets[0],
                record.sets[1],
                record.camera_difference_px,
                record.camera_difference_ratio,
                record.kept
            ));
        }
        self.held = Some(record.kept.clone());
        self.alternation = Some(record);
        kept
    }

    /// The readout time estimated from the neighbouring video frames, when they determine it;
    /// `None` when they do not, and the rolling shutter is then left out for good (the terms
    /// are to be selected again).
    fn with_readout_time(
        &mut self,
        iteration: usize,
        selected: Selected,
        neighbour_observations: &[crate::adjust::Observation],
    ) -> Option<Selected> {
        let LoopInput {
            config,
            log,
            frame_interval_s,
            ..
        } = self.fixed;
        let held_ms = 1e3 * selected.problem.global[BrownModel::READOUT];
        // The neighbours must tie the motions to time: a readout time outside the frame
        // interval, neighbours weighted next to nothing (their residuals 100 × the frames'),
        // or an adjustment that fails with them, leave the motions free, and their drift
        // along u0 + p2 runs the loop away (BoofCV's real video). The rolling shutter is then
        // left out for good.
        let accepted = match estimate_readout_time(
            selected,
            neighbour_observations,
            &self.selection,
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
        match accepted {
            Ok(e) => Some(e),
            Err(why) => {
                let msg = format!(
                    "iteration {iteration}: the neighbouring video frames do not determine the readout time ({why}): the rolling shutter is left out and the terms selected again"
                );
                log(&msg);
                self.warnings.push(msg);
                self.selection.rolling_shutter = None;
                // A held model with a rolling shutter cannot be kept once it is left out.
                if self.held.as_ref().is_some_and(|c| c.rolling_shutter) {
                    self.held = None;
                }
                None
            }
        }
    }
}

/// The log line of an adjusted iteration.
fn iteration_line(
    iteration: usize,
    m: &Matching,
    views: usize,
    selected: &Selected,
    change: Option<(f64, f64)>,
) -> String {
    format!(
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
    )
}

/// The log line of the frames left out of an iteration's adjustment.
fn dropped_line(iteration: usize, dropped_frames: &[usize], a1: &Algorithm1) -> String {
    format!(
        "iteration {iteration}: {} frame(s) left out of the adjustment, fewer than {MIN_FRAME_OBSERVATIONS} target observations: {}",
        dropped_frames.len(),
        dropped_frames
            .iter()
            .map(|&k| a1.frames[k].name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    )
}
