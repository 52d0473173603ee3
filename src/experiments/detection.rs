//! Detection accuracy on simulated frames: recall, precision and centre errors of
//! [`crate::detect`] against the simulator's truth.
//!
//! Frames are rendered in memory. A target *must* be found when the truth lists it with a
//! margin of 4 px from the border and its semi-minor axis is at least `min_semi_minor_px`; a
//! detection that matches a target the truth lists with any margin (fully inside, unoccluded)
//! but that need not be found is neither credited nor counted false. Any other detection is a
//! false positive. A detection matches a truth target when its centre is within
//! `max(1.5 px, 0.3·b)` of the truth's fitted ellipse centre and its semi-axes agree within
//! 30 %.

use serde::{Deserialize, Serialize};

use crate::detect::{DetectConfig, detect_in_frame};
use crate::geometry::conic::Ellipse;
use crate::sim::lab::{LabConfig, build_scene, path, reference_irradiance};
use crate::sim::render::{RayGrid, RenderConfig, exposure_gain, render_frame};
use crate::sim::simulate::{SimulateOptions, texel_size};
use crate::sim::truth::frame_truth;

/// One evaluation setting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalConfig {
    /// Simulation options (device, size, seed, rendering).
    pub options: SimulateOptions,
    /// Lab content and number of frames.
    pub lab: LabConfig,
    /// Detection options.
    pub detect: DetectConfig,
    /// Targets smaller than this (semi-minor, px) need not be found.
    pub min_semi_minor_px: f64,
}

/// The outcome.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EvalResult {
    /// Frames evaluated.
    pub frames: usize,
    /// Targets that had to be found.
    pub required: usize,
    /// Of those, found.
    pub found: usize,
    /// Detections matching nothing.
    pub false_positives: usize,
    /// Those detections, in frame order.
    pub false_detections: Vec<crate::detect::DetectedEllipse>,
    /// The detections of the targets found, matching `errors`.
    pub found_detections: Vec<crate::detect::DetectedEllipse>,
    /// found / required.
    pub recall: f64,
    /// found / (found + false positives).
    pub precision: f64,
    /// RMS centre error of the found targets against the truth's fitted ellipse (px).
    pub centre_rms_px: f64,
    /// 99th percentile of the centre error (px).
    pub centre_p99_px: f64,
    /// Largest centre error (px).
    pub centre_max_px: f64,
    /// Centre errors of the found targets (px), in frame order.
    #[serde(skip)]
    pub errors: Vec<f64>,
    /// Semi-minor axes of the found targets (px), matching `errors`.
    #[serde(skip)]
    pub semi_minor: Vec<f64>,
}

fn matches(det: &Ellipse, truth: &Ellipse) -> bool {
    (det.centre() - truth.centre()).norm() <= (0.3 * truth.b).max(1.5)
        && (det.a / truth.a - 1.0).abs() <= 0.3
        && (det.b / truth.b - 1.0).abs() <= 0.3
}

/// Renders the lab frames of `config` and scores the detector on them.
///
/// # Errors
///
/// A message for bad options or a frame that cannot be rendered.
pub fn evaluate(config: &EvalConfig) -> Result<EvalResult, String> {
    config.options.validate().map_err(|e| e.to_string())?;
    config.lab.validate().map_err(|e| e.to_string())?;
    let camera = config.options.camera().map_err(|e| e.to_string())?;
    let scene = build_scene(&config.lab, texel_size(&camera), config.options.seed);
    let stations = path(&config.lab, config.options.seed);
    let render: &RenderConfig = &config.options.render;
    let gain = exposure_gain(render, reference_irradiance(&scene, &config.lab));
    let rays = RayGrid::new(&camera);
    let mut r = EvalResult {
        frames: stations.len(),
        ..Default::default()
    };
    for (k, st) in stations.iter().enumerate() {
        let frame = render_frame(
            &scene,
            &camera,
            &rays,
            &st.cam_from_world,
            gain,
            render,
            config.options.seed,
            k as u64,
        )
        .map_err(|e| e.to_string())?;
        let truth_any = frame_truth(
            &scene,
            &camera,
            k as u32 + 1,
            "",
            &st.cam_from_world,
            st.orientation,
            0.0,
        );
        let truth_must = frame_truth(
            &scene,
            &camera,
            k as u32 + 1,
            "",
            &st.cam_from_world,
            st.orientation,
            4.0,
        );
        let det = detect_in_frame(&image::DynamicImage::ImageRgb8(frame.image), &config.detect)
            .map_err(|e| e.to_string())?;
        let required: Vec<_> = truth_must
            .targets
            .iter()
            .filter(|t| t.fitted.b >= config.min_semi_minor_px)
            .collect();
        r.required += required.len();
        let mut used = vec![false; required.len()];
        for d in &det.ellipses {
            let e = d.ellipse();
            if let Some((i, t)) = required
                .iter()
                .enumerate()
                .find(|(i, t)| !used[*i] && matches(&e, &t.fitted))
            {
                used[i] = true;
                r.found += 1;
                r.errors.push((e.centre() - t.fitted.centre()).norm());
                r.semi_minor.push(t.fitted.b);
                r.found_detections.push(d.clone());
            } else if !truth_any.targets.iter().any(|t| matches(&e, &t.fitted)) {
                r.false_positives += 1;
                r.false_detections.push(d.clone());
            }
        }
    }
    r.recall = if r.required == 0 {
        1.0
    } else {
        r.found as f64 / r.required as f64
    };
    r.precision = if r.found + r.false_positives == 0 {
        1.0
    } else {
        r.found as f64 / (r.found + r.false_positives) as f64
    };
    let mut sorted = r.errors.clone();
    sorted.sort_by(f64::total_cmp);
    if !sorted.is_empty() {
        r.centre_rms_px = (sorted.iter().map(|e| e * e).sum::<f64>() / sorted.len() as f64).sqrt();
        r.centre_p99_px =
            sorted[((sorted.len() as f64 * 0.99).ceil() as usize).min(sorted.len()) - 1];
        r.centre_max_px = sorted[sorted.len() - 1];
    }
    Ok(r)
}
