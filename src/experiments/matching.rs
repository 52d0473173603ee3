//! Matching (Algorithm 2) and centre correction (Algorithm 3) scored against the simulator's
//! truth: the paper's Table II metrics and the corrected-centre accuracy.
//!
//! A scenario is a simulated lab without pixels ([`lab_geometry`]): the SfM stand-in's model
//! (noisy poses in an arbitrary similarity frame, noisy features with gross mismatches) and, as
//! detections, the truth's fitted ellipses — what a perfect detector finds — perturbed by the
//! detector's measured noise (centre σ = 0.01 px per coordinate by default; the detection
//! issue measured 0.0088 px RMS on rendered 4K frames). Targets with a semi-minor axis under
//! `min_semi_minor_px` are left out, as the detector's acceptance does.
//!
//! Definitions (standard sense, over pairs of detections in different frames): a predicted
//! correspondence is two views in one output track; TP: predicted and of one target; FP:
//! predicted but of different targets (a mismatch); FN: of one target but not predicted; TN:
//! the rest. precision = TP/(TP+FP), recall = TP/(TP+FN), accuracy = (TP+TN)/all, F =
//! 2PR/(P+R). The paper calls freedom from mismatches "recall"; here that is precision.

use nalgebra::Vector2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::calibrate::matching::{MatchConfig, Matching, match_targets};
use crate::calibrate::poses::consistent_poses;
use crate::calibrate::refine::{Algorithm1, RefineConfig, algorithm1};
use crate::calibrate::views::{FrameCamera, TargetObservation, observations};
use crate::geometry::conic::Ellipse;
use crate::io::colmap::Reconstruction;
use crate::robust::standard_normal as gaussian;
use crate::sim::lab::LabConfig;
use crate::sim::simulate::{SimulateOptions, lab_geometry};
use crate::sim::truth::Truth;

use super::PresetRuns;

/// A matching scenario.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    /// Simulation options (device, size, seed, SfM stand-in noise).
    pub options: SimulateOptions,
    /// Lab content and number of frames.
    pub lab: LabConfig,
    /// σ of the simulated detections' centres per coordinate (px); axes get the same σ.
    pub centre_noise_px: f64,
    /// Targets with a smaller semi-minor axis are not detected (px).
    pub min_semi_minor_px: f64,
    /// Use the true intrinsics (true) or the SfM model's camera (false).
    pub true_intrinsics: bool,
}

impl Default for Scenario {
    fn default() -> Self {
        Scenario {
            options: SimulateOptions::default(),
            lab: LabConfig::default(),
            centre_noise_px: 0.01,
            min_semi_minor_px: crate::detect::MIN_SEMI_MINOR_TO_MEASURE_PX,
            true_intrinsics: true,
        }
    }
}

/// A scenario made ready for matching.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// The truth.
    pub truth: Truth,
    /// The SfM stand-in's model.
    pub model: Reconstruction,
    /// Algorithm 1 on it.
    pub algorithm1: Algorithm1,
    /// Per model frame, its camera.
    pub cameras: Vec<FrameCamera>,
    /// Per model frame, the simulated detections in undistorted pixels.
    pub observations: Vec<Vec<TargetObservation>>,
    /// Per model frame, per observation: the target id and the truth's index of the view.
    pub ids: Vec<Vec<(u32, usize)>>,
    /// Per model frame, the truth frame index.
    pub truth_frame: Vec<usize>,
}

/// `e` with the detector's noise: σ on the centre and the axes (px), σ/a on the orientation.
pub(crate) fn with_detector_noise(e: &Ellipse, sigma: f64, rng: &mut ChaCha8Rng) -> Ellipse {
    Ellipse::new(
        e.cx + sigma * gaussian(rng),
        e.cy + sigma * gaussian(rng),
        e.a + sigma * gaussian(rng),
        e.b + sigma * gaussian(rng),
        e.theta + sigma / e.a * gaussian(rng),
    )
}

/// Simulated detections of a truth frame: fitted ellipses with noise, and their (id, view
/// index).
pub(crate) fn detections(
    truth: &Truth,
    frame: usize,
    scenario: &Scenario,
    rng: &mut ChaCha8Rng,
) -> (Vec<Ellipse>, Vec<(u32, usize)>) {
    let s = scenario.centre_noise_px;
    truth.frames[frame]
        .targets
        .iter()
        .enumerate()
        .filter(|(_, t)| t.fitted.b >= scenario.min_semi_minor_px)
        .map(|(k, t)| (with_detector_noise(&t.fitted, s, rng), (t.id, k)))
        .unzip()
}

/// Builds the scenario: truth, stand-in model, Algorithm 1, detections.
///
/// # Errors
///
/// A message for bad options.
pub fn prepare(scenario: &Scenario) -> Result<Prepared, String> {
    let (truth, model) =
        lab_geometry(&scenario.options, &scenario.lab).map_err(|e| e.to_string())?;
    let intrinsics = scenario.true_intrinsics.then_some(truth.camera.intrinsics);
    let refine = RefineConfig {
        seed: scenario.options.seed,
        ..RefineConfig::default()
    };
    // Given intrinsics meet poses adjusted with the SfM program's own camera: re-adjusted to
    // them first, as the product does (`match --device`).
    let a1 = match &intrinsics {
        Some(i) => {
            consistent_poses(&model, i, &refine, &crate::adjust::AdjustConfig::default())
                .map_err(|e| e.to_string())?
                .a1
        }
        None => algorithm1(&model, None, &refine).map_err(|e| e.to_string())?,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(scenario.options.seed ^ 0x00DE_7EC7);
    let mut cameras = Vec::new();
    let mut obs = Vec::new();
    let mut ids = Vec::new();
    let mut truth_frame = Vec::new();
    for f in &a1.frames {
        let k = truth
            .frames
            .iter()
            .position(|t| t.name == f.name)
            .ok_or_else(|| format!("frame {} not in the truth", f.name))?;
        let (ellipses, frame_ids) = detections(&truth, k, scenario, &mut rng);
        let o = observations(cameras.len(), &f.camera, &ellipses);
        // `observations` drops detections it cannot undistort; keep ids aligned.
        let kept: Vec<(u32, usize)> = o.iter().map(|x| frame_ids[x.index]).collect();
        cameras.push(f.camera);
        obs.push(o);
        ids.push(kept);
        truth_frame.push(k);
    }
    Ok(Prepared {
        truth,
        model,
        algorithm1: a1,
        cameras,
        observations: obs,
        ids,
        truth_frame,
    })
}

/// Runs Algorithm 2 on a prepared scenario.
#[must_use]
pub fn run(prepared: &Prepared, config: &MatchConfig) -> Matching {
    let size = (prepared.truth.camera.width, prepared.truth.camera.height);
    match_targets(
        &prepared.cameras,
        &prepared.observations,
        &prepared.algorithm1.pairs,
        size,
        prepared.algorithm1.reprojection_sigma,
        config,
    )
}

/// Table II's metrics.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MatchScores {
    /// True positives (correspondences).
    pub tp: u64,
    /// False positives (mismatches).
    pub fp: u64,
    /// False negatives (missed correspondences).
    pub fn_: u64,
    /// True negatives.
    pub tn: u64,
    /// TP/(TP+FP).
    pub precision: f64,
    /// TP/(TP+FN).
    pub recall: f64,
    /// (TP+TN)/all.
    pub accuracy: f64,
    /// 2PR/(P+R).
    pub f_measure: f64,
    /// Output tracks.
    pub tracks: usize,
    /// Tracks holding views of more than one target.
    pub mixed_tracks: usize,
}

/// Scores a matching against the truth (definitions in the module documentation).
#[must_use]
pub fn score(prepared: &Prepared, matching: &Matching) -> MatchScores {
    let mut s = MatchScores {
        tracks: matching.tracks.len(),
        ..Default::default()
    };
    for t in &matching.tracks {
        let ids: Vec<u32> = t
            .views
            .iter()
            .map(|v| prepared.ids[v.frame][v.obs].0)
            .collect();
        let mut mixed = false;
        for (x, a) in ids.iter().enumerate() {
            for b in &ids[x + 1..] {
                if a == b {
                    s.tp += 1;
                } else {
                    s.fp += 1;
                    mixed = true;
                }
            }
        }
        s.mixed_tracks += usize::from(mixed);
    }
    let mut per_id: std::collections::HashMap<u32, u64> = std::collections::HashMap::new();
    for frame in &prepared.ids {
        for (id, _) in frame {
            *per_id.entry(*id).or_default() += 1;
        }
    }
    let positives: u64 = per_id.values().map(|n| n * (n - 1) / 2).sum();
    let n: u64 = per_id.values().sum();
    let same_frame: u64 = prepared
        .ids
        .iter()
        .map(|f| (f.len() as u64) * (f.len() as u64).saturating_sub(1) / 2)
        .sum();
    let all = n * n.saturating_sub(1) / 2 - same_frame;
    s.fn_ = positives.saturating_sub(s.tp);
    s.tn = all.saturating_sub(s.tp + s.fp + s.fn_);
    s.with_rates()
}

impl MatchScores {
    /// Precision, recall, accuracy and F-measure from the four counts.
    #[must_use]
    pub fn with_rates(mut self) -> Self {
        let ratio = |a: u64, b: u64| if b == 0 { 0.0 } else { a as f64 / b as f64 };
        self.precision = ratio(self.tp, self.tp + self.fp);
        self.recall = ratio(self.tp, self.tp + self.fn_);
        self.accuracy = ratio(self.tp + self.tn, self.tp + self.tn + self.fp + self.fn_);
        self.f_measure = if self.precision + self.recall > 0.0 {
            2.0 * self.precision * self.recall / (self.precision + self.recall)
        } else {
            0.0
        };
        self
    }

    /// The counts of `self` and `other` summed, rates recomputed (tracks summed too).
    #[must_use]
    pub fn plus(&self, other: &MatchScores) -> MatchScores {
        MatchScores {
            tp: self.tp + other.tp,
            fp: self.fp + other.fp,
            fn_: self.fn_ + other.fn_,
            tn: self.tn + other.tn,
            tracks: self.tracks + other.tracks,
            mixed_tracks: self.mixed_tracks + other.mixed_tracks,
            ..MatchScores::default()
        }
        .with_rates()
    }
}

/// Centre accuracy of matched views whose true eccentricity exceeds a threshold.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CentreScores {
    /// Views counted.
    pub views: usize,
    /// Of those, views Algorithm 3 corrected.
    pub corrected: usize,
    /// Mean true eccentricity of the counted views (px).
    pub mean_eccentricity_px: f64,
    /// RMS distance of the fitted (detected) centres from the true centre's image (px).
    pub fitted_rms_px: f64,
    /// RMS distance of the output centres (corrected where Algorithm 3 gave one).
    pub corrected_rms_px: f64,
    /// fitted / corrected.
    pub improvement: f64,
}

/// Compares each matched view's fitted and output centre with the image of the target's true
/// centre, in observed (distorted) pixels, for views whose true eccentricity (truth's fitted
/// ellipse centre minus the true centre's image) exceeds `min_eccentricity_px`.
#[must_use]
pub fn centre_scores(
    prepared: &Prepared,
    matching: &Matching,
    min_eccentricity_px: f64,
) -> CentreScores {
    let mut s = CentreScores::default();
    let (mut e_sum, mut f_sq, mut c_sq) = (0.0, 0.0, 0.0);
    for t in &matching.tracks {
        for v in &t.views {
            let (_, view) = prepared.ids[v.frame][v.obs];
            let tv = &prepared.truth.frames[prepared.truth_frame[v.frame]].targets[view];
            let truth_px = Vector2::new(tv.centre_px[0], tv.centre_px[1]);
            let ecc = (tv.fitted.centre() - truth_px).norm();
            if ecc <= min_eccentricity_px {
                continue;
            }
            let cam = &prepared.cameras[v.frame];
            let detected = prepared.observations[v.frame][v.obs].detected.centre();
            let Some(out) = cam.distort(&v.best_centre()) else {
                continue;
            };
            s.views += 1;
            s.corrected += usize::from(v.corrected.is_some());
            e_sum += ecc;
            f_sq += (detected - truth_px).norm_squared();
            c_sq += (out - truth_px).norm_squared();
        }
    }
    if s.views > 0 {
        let n = s.views as f64;
        s.mean_eccentricity_px = e_sum / n;
        s.fitted_rms_px = (f_sq / n).sqrt();
        s.corrected_rms_px = (c_sq / n).sqrt();
        s.improvement = s.fitted_rms_px / s.corrected_rms_px.max(1e-300);
    }
    s
}

/// Table II's runs as the paper made them: 90 frames of 3840×2160 of each device preset's lab
/// (270 frames).
#[must_use]
pub fn table2_runs() -> PresetRuns {
    PresetRuns::every_preset(3840, 90)
}

/// One setting on one device.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceScores {
    /// Device preset.
    pub device: String,
    /// Table II's metrics.
    pub scores: MatchScores,
    /// Centre accuracy of views with true eccentricity over 0.5 px.
    pub centres: CentreScores,
}

/// One row of Table II.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Table2Row {
    /// The setting's name.
    pub setting: String,
    /// Per device.
    pub devices: Vec<DeviceScores>,
    /// Over all devices.
    pub total: MatchScores,
    /// The paper's F-measure for this setting (Table II, real data).
    pub paper_f_measure: f64,
}

/// Table II.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Table2 {
    /// How it was run.
    pub options: PresetRuns,
    /// Frames and detections per device.
    pub detections: Vec<(String, usize, usize)>,
    /// The three settings.
    pub rows: Vec<Table2Row>,
}

/// The paper's three settings: Algorithm 2 without robust triangulation, with it, and with it
/// and Algorithm 3's centres, each with the paper's F-measure.
#[must_use]
pub fn table2_settings() -> [(&'static str, MatchConfig, f64); 3] {
    [
        (
            "Algorithm 2 without robust triangulation",
            MatchConfig {
                robust_triangulation: false,
                correct_before_triangulation: false,
                correct_centres: false,
                ..MatchConfig::default()
            },
            0.9471,
        ),
        (
            "with robust triangulation",
            MatchConfig {
                correct_before_triangulation: false,
                correct_centres: false,
                ..MatchConfig::default()
            },
            0.9675,
        ),
        (
            "with robust triangulation and corrected centres",
            MatchConfig::default(),
            0.9840,
        ),
    ]
}

/// Runs Table II: per device, a simulated lab ([`prepare`]), then each setting.
///
/// # Errors
///
/// A message naming the device whose scenario failed.
pub fn table2(options: &PresetRuns, log: &dyn Fn(&str)) -> Result<Table2, String> {
    let settings = table2_settings();
    let mut rows: Vec<Table2Row> = settings
        .iter()
        .map(|(name, _, paper)| Table2Row {
            setting: (*name).to_string(),
            devices: Vec::new(),
            total: MatchScores::default(),
            paper_f_measure: *paper,
        })
        .collect();
    let mut detections = Vec::new();
    for device in &options.devices {
        let scenario = Scenario {
            options: options.simulate_options(device, ""),
            lab: LabConfig {
                frames: options.frames,
                ..LabConfig::default()
            },
            ..Scenario::default()
        };
        let prepared = prepare(&scenario).map_err(|e| format!("{device}: {e}"))?;
        let n: usize = prepared.observations.iter().map(Vec::len).sum();
        log(&format!(
            "{device}: {} frames, {n} detections, {} pairs, Algorithm 1 σ {:.2} px",
            prepared.cameras.len(),
            prepared.algorithm1.pairs.len(),
            prepared.algorithm1.reprojection_sigma
        ));
        detections.push((device.clone(), prepared.cameras.len(), n));
        for ((_, config, _), row) in settings.iter().zip(&mut rows) {
            let m = run(&prepared, config);
            let scores = score(&prepared, &m);
            let centres = centre_scores(&prepared, &m, 0.5);
            log(&format!(
                "  {}: TP {} FP {} FN {}, F {:.4}; centres {:.3} → {:.4} px",
                row.setting,
                scores.tp,
                scores.fp,
                scores.fn_,
                scores.f_measure,
                centres.fitted_rms_px,
                centres.corrected_rms_px
            ));
            row.total = row.total.plus(&scores);
            row.devices.push(DeviceScores {
                device: device.clone(),
                scores,
                centres,
            });
        }
    }
    Ok(Table2 {
        options: options.clone(),
        detections,
        rows,
    })
}

impl Table2 {
    /// The experiments' Markdown section for Table II: the labs, how the matches were counted,
    /// and the table.
    #[must_use]
    pub fn section_markdown(&self) -> String {
        let t = self;
        let o = &t.options;
        let detections: usize = t.detections.iter().map(|d| d.2).sum();
        let frames: usize = t.detections.iter().map(|d| d.1).sum();
        format!(
            "\n## Table II — matching targets across views\n\nSimulated labs of {} ({} frames of {}x{} each, seed {}; {frames} frames, {detections} detections in all): the SfM stand-in's own bundle adjustment of poses perturbed by 0.1° and 3 mm, features with 0.5 px noise and 3 % gross mismatches, its poses re-adjusted to the true intrinsics; detections are the truth's fitted ellipses with σ = 0.01 px. Counted over pairs of detections in different frames (precision = freedom from mismatches, which the paper calls recall).\n\n{}",
            o.devices.join(", "),
            o.frames,
            o.width,
            o.width * 9 / 16,
            o.seed,
            t.markdown()
        )
    }

    /// The table over all devices, beside the paper's F-measure, and the corrected-centre
    /// accuracy per device, as Markdown.
    #[must_use]
    pub fn markdown(&self) -> String {
        let pct = |x: f64| format!("{:.2} %", 100.0 * x);
        let mut md = String::from(
            "| setting | TP | FP | FN | precision | recall | accuracy | F-measure | paper's F |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
        );
        for r in &self.rows {
            let t = &r.total;
            md.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} | {:.4} % | {} | {} |\n",
                r.setting,
                t.tp,
                t.fp,
                t.fn_,
                pct(t.precision),
                pct(t.recall),
                100.0 * t.accuracy,
                pct(t.f_measure),
                pct(r.paper_f_measure)
            ));
        }
        if let Some(last) = self.rows.last() {
            md.push_str(
                "\nCentres of views with true eccentricity over 0.5 px (last setting), RMS distance from the image of the true centre:\n\n| device | views | fitted (px) | corrected (px) | improvement |\n| --- | ---: | ---: | ---: | ---: |\n",
            );
            for d in &last.devices {
                md.push_str(&format!(
                    "| {} | {} | {:.3} | {:.4} | {:.1}x |\n",
                    d.device,
                    d.centres.views,
                    d.centres.fitted_rms_px,
                    d.centres.corrected_rms_px,
                    d.centres.improvement
                ));
            }
        }
        md
    }
}
