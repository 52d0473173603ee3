//! Term selection and the calibration loop against the simulator's truth.

use nalgebra::{Vector2, Vector3};
use pipemeasure::adjust::{AdjustConfig, BrownModel, Observation, Problem};
use pipemeasure::calibrate::selection::{SelectionConfig, select_terms};
use pipemeasure::camera::{Intrinsics, Term};
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::sfm::gaussian;
use pipemeasure::sim::simulate::{SimulateOptions, lab_geometry};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A target adjustment built from the truth: true poses and centres, observations at the true
/// projected centres plus `noise` px.
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
    let ids: Vec<u32> = truth.targets.iter().map(|t| t.id).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut observations = Vec::new();
    let mut seen = vec![0usize; ids.len()];
    for (k, f) in truth.frames.iter().enumerate() {
        for t in &f.targets {
            if t.fitted.b < 4.0 {
                continue;
            }
            let p = ids.iter().position(|&i| i == t.id).unwrap();
            seen[p] += 1;
            observations.push(Observation {
                camera: k,
                point: p,
                uv: Vector2::new(t.centre_px[0], t.centre_px[1])
                    + noise * Vector2::new(gaussian(&mut rng), gaussian(&mut rng)),
                weight: 1.0,
            });
        }
    }
    observations.retain(|o| seen[o.point] >= 3);
    let mut index = vec![usize::MAX; ids.len()];
    let mut points = Vec::new();
    for (p, t) in truth.targets.iter().enumerate() {
        if seen[p] >= 3 {
            index[p] = points.len();
            points.push(Vector3::from(t.centre));
        }
    }
    for o in &mut observations {
        o.point = index[o.point];
    }
    let t = truth.camera.intrinsics;
    let start = Intrinsics::pinhole(t.c * 1.01, t.u0 + 5.0, t.v0 - 5.0);
    let problem = Problem::new(
        BrownModel,
        truth.frames.iter().map(|f| f.cam_from_world()).collect(),
        Vec::new(),
        start.to_array().to_vec(),
        points,
        observations,
    )
    .unwrap();
    (problem, t)
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
