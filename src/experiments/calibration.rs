//! The calibration loop scored against the simulator's truth: intrinsics against the preset,
//! the distortion model's largest difference over the frame, the selected terms against the
//! terms the truth has above 0.1 px effect.
//!
//! Like [`super::matching`], a scenario starts from the SfM stand-in's model and simulated
//! detections (the truth's fitted ellipses plus the detector's noise) rather than rendered
//! pixels; `pipemeasure calibrate` on rendered frames is what made `calibrations/*.json`.

use nalgebra::{Vector2, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::matching::{Scenario, detections};
use crate::adjust::{BrownModel, FixedParameters, Observation, Problem};
use crate::calibrate::pipeline::{CalibrateConfig, Calibration, CalibrationInput};
use crate::calibrate::{DeviceConfig, calibrate_device};
use crate::camera::{Intrinsics, Term};
use crate::geometry::conic::Ellipse;
use crate::io::colmap::Reconstruction;
use crate::robust::standard_normal as gaussian;
use crate::sim::simulate::lab_geometry;
use crate::sim::truth::Truth;

/// A scenario ready to calibrate: the truth, the model, the detections per model frame.
#[derive(Clone, Debug)]
pub struct CalibrationScenario {
    /// The truth.
    pub truth: Truth,
    /// The SfM stand-in's model.
    pub model: Reconstruction,
    /// Per registered image (image-id order), simulated detections (observed pixels).
    pub detections: Vec<Vec<Ellipse>>,
}

/// Builds a calibration scenario.
///
/// # Errors
/// A message for bad options or a frame missing from the truth.
pub fn prepare(scenario: &Scenario) -> Result<CalibrationScenario, String> {
    let (truth, model) =
        lab_geometry(&scenario.options, &scenario.lab).map_err(|e| e.to_string())?;
    let mut rng = ChaCha8Rng::seed_from_u64(scenario.options.seed ^ 0x00DE_7EC7);
    let mut out = Vec::new();
    for image in model.images.values() {
        let k = truth
            .frames
            .iter()
            .position(|t| t.name == image.name)
            .ok_or_else(|| format!("frame {} not in the truth", image.name))?;
        out.push(detections(&truth, k, scenario, &mut rng).0);
    }
    Ok(CalibrationScenario {
        truth,
        model,
        detections: out,
    })
}

/// Runs the calibration on a scenario.
///
/// # Errors
/// The calibration's error, as text.
pub fn run(
    s: &CalibrationScenario,
    config: &CalibrateConfig,
    log: &dyn Fn(&str),
) -> Result<Calibration, String> {
    let input = CalibrationInput {
        model: &s.model,
        detections: &s.detections,
        image_size: (s.truth.camera.width, s.truth.camera.height),
        neighbours: &[],
    };
    let config = DeviceConfig {
        calibrate: config.clone(),
        cross_validate: false,
    };
    calibrate_device(&input, &config, log)
        .map(|d| d.calibration)
        .map_err(|e| e.to_string())
}

/// A calibration compared with the truth.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationScore {
    /// Per term: (name, truth, estimate, σ).
    pub terms: Vec<(String, f64, f64, f64)>,
    /// Largest difference of the distortion displacement over the frame (px).
    pub max_distortion_difference_px: f64,
    /// Terms selected.
    pub selected: Vec<String>,
    /// Terms the truth has with more than 0.1 px effect somewhere in the frame.
    pub significant_truth_terms: Vec<String>,
    /// σ0 (px).
    pub sigma0: f64,
    /// Residual RMS per coordinate (px).
    pub residual_rms_px: f64,
    /// Targets and observations adjusted.
    pub targets: usize,
    /// Observations adjusted.
    pub observations: usize,
    /// Loop iterations.
    pub iterations: usize,
}

/// Grid of ideal normalised points covering the frame of `truth`'s camera (undistorted with
/// the true model).
fn frame_grid(truth: &Truth) -> Vec<Vector2<f64>> {
    let cam = &truth.camera;
    let (w, h) = (f64::from(cam.width), f64::from(cam.height));
    let n = 40;
    let mut out = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            let uv = Vector2::new(
                w * f64::from(i) / f64::from(n),
                h * f64::from(j) / f64::from(n),
            );
            if let Ok(xy) = cam.intrinsics.ideal_from_pixel(&uv) {
                out.push(xy);
            }
        }
    }
    out
}

/// The distortion displacement `c·(distort(x) − x)` of a model at ideal point `x` (px).
fn displacement(i: &Intrinsics, x: &Vector2<f64>) -> Vector2<f64> {
    i.c * (i.distort(x) - x)
}

/// Largest difference of the distortion displacement of two models over the frame (px).
#[must_use]
pub fn max_distortion_difference(truth: &Truth, estimate: &Intrinsics) -> f64 {
    frame_grid(truth)
        .iter()
        .map(|x| (displacement(estimate, x) - displacement(&truth.camera.intrinsics, x)).norm())
        .fold(0.0, f64::max)
}

/// Largest effect (px) of each distortion term of `i` over the frame of `truth`.
fn term_effects(truth: &Truth, i: &Intrinsics) -> Vec<(Term, f64)> {
    let grid = frame_grid(truth);
    Term::ALL[3..]
        .iter()
        .map(|&t| {
            let mut without = *i;
            without.set(t, 0.0);
            let effect = grid
                .iter()
                .map(|x| {
                    let a = i.pixel_from_distorted(&i.distort(x));
                    let b = without.pixel_from_distorted(&without.distort(x));
                    (a - b).norm()
                })
                .fold(0.0, f64::max);
            (t, effect)
        })
        .collect()
}

/// Scores a calibration against the truth.
#[must_use]
pub fn score(s: &CalibrationScenario, cal: &Calibration) -> CalibrationScore {
    let truth = s.truth.camera.intrinsics;
    let terms = Term::ALL
        .iter()
        .map(|&t| {
            (
                t.name().to_string(),
                truth.get(t),
                cal.intrinsics.get(t),
                cal.std_dev[t.index()],
            )
        })
        .collect();
    CalibrationScore {
        terms,
        max_distortion_difference_px: max_distortion_difference(&s.truth, &cal.intrinsics),
        selected: cal.terms.iter().map(|t| t.name().to_string()).collect(),
        significant_truth_terms: term_effects(&s.truth, &truth)
            .into_iter()
            .filter(|(_, e)| *e > 0.1)
            .map(|(t, _)| t.name().to_string())
            .collect(),
        sigma0: cal.sigma0,
        residual_rms_px: cal.residual_rms_px,
        targets: cal.points.len(),
        observations: cal.observations.len(),
        iterations: cal.iterations.len(),
    }
}

/// The semi-minor axis (px) from which a true target view counts in [`truth_target_points`].
pub const TRUTH_MIN_SEMI_MINOR_PX: f64 = 4.0;

/// The adjustment points of a simulated lab's truth: the targets with a semi-minor axis of at
/// least [`TRUTH_MIN_SEMI_MINOR_PX`] in at least three frames. Returns, per truth target (in
/// `truth.targets` order), its index among the points (`None` when left out), and the points
/// (true centres).
#[must_use]
pub fn truth_target_points(truth: &Truth) -> (Vec<Option<usize>>, Vec<Vector3<f64>>) {
    let index_of = truth_target_index(truth);
    let mut seen = vec![0usize; truth.targets.len()];
    for t in truth.frames.iter().flat_map(|f| &f.targets) {
        if let Some(&p) = index_of.get(&t.id)
            && t.fitted.b >= TRUTH_MIN_SEMI_MINOR_PX
        {
            seen[p] += 1;
        }
    }
    let mut points = Vec::new();
    let point_of = truth
        .targets
        .iter()
        .zip(&seen)
        .map(|(t, &n)| {
            (n >= 3).then(|| {
                points.push(Vector3::from(t.centre));
                points.len() - 1
            })
        })
        .collect();
    (point_of, points)
}

/// Target id → index in `truth.targets`.
#[must_use]
pub fn truth_target_index(truth: &Truth) -> std::collections::HashMap<u32, usize> {
    truth
        .targets
        .iter()
        .enumerate()
        .map(|(k, t)| (t.id, k))
        .collect()
}

/// The target adjustment of a simulated lab built from its truth: true poses and target
/// centres ([`truth_target_points`]), observations at the true projected centres plus
/// `noise_px` Gaussian noise, and start intrinsics off by 1 % in c and 5 px in u0, v0 with no
/// distortion. For the selection tests and the adjustment benchmark.
#[must_use]
pub fn truth_target_problem(truth: &Truth, noise_px: f64, seed: u64) -> Problem<BrownModel> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let index_of = truth_target_index(truth);
    let (point_of, points) = truth_target_points(truth);
    let mut observations = Vec::new();
    for (k, f) in truth.frames.iter().enumerate() {
        for t in &f.targets {
            let Some(&p) = index_of.get(&t.id) else {
                continue;
            };
            if t.fitted.b < TRUTH_MIN_SEMI_MINOR_PX {
                continue;
            }
            // The noise is drawn for every usable view, kept or not (the draws as before).
            let uv = Vector2::new(t.centre_px[0], t.centre_px[1])
                + noise_px * Vector2::new(gaussian(&mut rng), gaussian(&mut rng));
            if let Some(point) = point_of[p] {
                observations.push(Observation {
                    camera: k,
                    point,
                    uv,
                    weight: 1.0,
                    time_offset_s: 0.0,
                });
            }
        }
    }
    let t = truth.camera.intrinsics;
    let start = Intrinsics::pinhole(t.c * 1.01, t.u0 + 5.0, t.v0 - 5.0);
    let mut problem = Problem {
        model: BrownModel::GLOBAL_SHUTTER,
        cam_from_world: truth.frames.iter().map(|f| f.cam_from_world()).collect(),
        local: Vec::new(),
        global: start.to_array().to_vec(),
        points,
        observations,
        fixed: FixedParameters::default(),
    };
    problem.fixed.global = vec![Term::K3.index(), Term::B1.index(), Term::B2.index()];
    problem
}
