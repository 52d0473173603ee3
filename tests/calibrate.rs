//! Term selection and the calibration loop against the simulator's truth.

#![allow(clippy::unwrap_used)]

use pipemeasure::adjust::{AdjustConfig, BrownModel, Problem};
use pipemeasure::calibrate::selection::{SelectionConfig, select_terms};
use pipemeasure::camera::{Intrinsics, Term};
use pipemeasure::experiments::calibration::truth_target_problem;
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::simulate::{SimulateOptions, lab_geometry};

fn truth_problem(
    device: &str,
    width: u32,
    frames: usize,
    noise: f64,
) -> (Problem<BrownModel>, Intrinsics) {
    let options = SimulateOptions {
        device: device.into(),
        width,
        height: width * 9 / 16,
        ..SimulateOptions::default()
    };
    let lab = LabConfig {
        frames,
        ..LabConfig::default()
    };
    let (truth, _) = lab_geometry(&options, &lab).unwrap();
    (
        truth_target_problem(&truth, noise, 5),
        truth.camera.intrinsics,
    )
}

fn check_selection(device: &str, width: u32, frames: usize, noise: f64, true_terms: &[Term]) {
    let (problem, truth) = truth_problem(device, width, frames, noise);
    let sel = select_terms(
        &problem,
        &SelectionConfig::default(),
        &AdjustConfig::default(),
        &|m| eprintln!("{m}"),
    )
    .unwrap();
    eprintln!("{:?}", sel.terms);
    for t in &Term::ALL[3..] {
        assert_eq!(
            sel.terms.contains(t),
            true_terms.contains(t),
            "{t}: selected {:?}, truth {true_terms:?}",
            sel.terms
        );
    }
    let std = sel.precision.global_std();
    for t in [Term::C, Term::U0, Term::V0] {
        let (e, x) = (sel.problem.global[t.index()], truth.get(t));
        assert!(
            (e - x).abs() < 3.0 * std[t.index()] + 1e-9,
            "{t}: {e} vs {x} ± {}",
            std[t.index()]
        );
    }
}

#[test]
fn selection_on_true_centres_finds_the_p30_terms() {
    check_selection(
        "p30",
        1920,
        40,
        0.02,
        &[Term::K1, Term::K2, Term::P1, Term::P2],
    );
}

#[test]
fn selection_on_true_centres_finds_the_s10_third_radial_term() {
    check_selection(
        "s10",
        3840,
        90,
        0.01,
        &[Term::K1, Term::K2, Term::K3, Term::P1, Term::P2],
    );
}

#[test]
fn a_network_without_roll_diversity_gets_a_loud_warning() {
    use pipemeasure::calibrate::pipeline::{CalibrateConfig, CalibrationInput, calibrate};
    use pipemeasure::experiments::calibration::prepare;
    use pipemeasure::experiments::matching::Scenario;
    use pipemeasure::sim::truth::Orientation;

    let mut scenario = Scenario::default();
    scenario.options.width = 1920;
    scenario.options.height = 1080;
    scenario.lab.frames = 40;
    let s = prepare(&scenario).unwrap();
    // Keep the landscape frames only.
    let landscape: Vec<bool> = s
        .model
        .images
        .values()
        .map(|i| {
            s.truth
                .frames
                .iter()
                .find(|f| f.name == i.name)
                .is_some_and(|f| f.orientation == Orientation::Landscape)
        })
        .collect();
    let model = s.model.with_images(&landscape);
    let detections: Vec<_> = s
        .detections
        .iter()
        .zip(&landscape)
        .filter(|(_, l)| **l)
        .map(|(d, _)| d.clone())
        .collect();
    assert!(detections.len() >= 15, "{}", detections.len());
    let input = CalibrationInput {
        model: &model,
        detections: &detections,
        image_size: (1920, 1080),
        neighbours: &[],
    };
    let cal = calibrate(&input, &CalibrateConfig::default(), &|_| {}).unwrap();
    assert!(
        cal.warnings.iter().any(|w| w.contains("same roll")),
        "{:?}",
        cal.warnings
    );
    // With both orientations (the full lab) there is no such warning.
    let input = CalibrationInput {
        model: &s.model,
        detections: &s.detections,
        image_size: (1920, 1080),
        neighbours: &[],
    };
    let cal = calibrate(&input, &CalibrateConfig::default(), &|_| {}).unwrap();
    assert!(
        !cal.warnings.iter().any(|w| w.contains("same roll")),
        "{:?}",
        cal.warnings
    );
}

/// Frames that see no target — real video has them: the camera turned away, motion blur — are
/// left out of the target adjustment instead of making its normal equations singular, and the
/// calibration of the rest still recovers the camera.
#[test]
fn frames_without_targets_are_left_out_of_the_adjustment() {
    use pipemeasure::calibrate::pipeline::{CalibrateConfig, CalibrationInput, calibrate};
    use pipemeasure::experiments::calibration::prepare;
    use pipemeasure::experiments::matching::Scenario;

    let mut scenario = Scenario::default();
    scenario.options.width = 1920;
    scenario.options.height = 1080;
    scenario.lab.frames = 30;
    let s = prepare(&scenario).unwrap();
    let mut detections = s.detections.clone();
    for k in [3, 11, 20] {
        detections[k].clear();
    }
    // One more frame keeps only two targets: too few to fix its pose.
    detections[7].truncate(2);
    let input = CalibrationInput {
        model: &s.model,
        detections: &detections,
        image_size: (1920, 1080),
        neighbours: &[],
    };
    let cal = calibrate(&input, &CalibrateConfig::default(), &|m| eprintln!("{m}")).unwrap();
    for k in [3, 7, 11, 20] {
        assert!(!cal.adjusted_frames.contains(&k), "frame {k} adjusted");
        assert!(cal.observations.iter().all(|o| o.frame != k));
    }
    assert_eq!(cal.adjusted_frames.len(), detections.len() - 4);
    let truth = s.truth.camera.intrinsics;
    for t in [Term::C, Term::U0, Term::V0] {
        let (e, x, sd) = (cal.intrinsics.get(t), truth.get(t), cal.std_dev[t.index()]);
        assert!((e - x).abs() < 3.0 * sd + 0.05, "{t}: {e} vs {x} ± {sd}");
    }
}
