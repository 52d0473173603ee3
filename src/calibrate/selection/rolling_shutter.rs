//! The rolling-shutter candidate of the term selection ([`super::select_terms`]): a motion per
//! frame (`(ω, ν)`, [`crate::camera::rolling`]) with the readout time held, kept by the same
//! significance and BIC tests as a group of terms, and refused when its row displacement is far
//! beyond what the residuals could show ([`MAX_SHEAR_OVER_RESIDUAL`]); then, when the frames'
//! neighbours in the video tie the motions to time, the readout time estimated from them
//! ([`estimate_readout_time`]) with the neighbours weighted by variance components, and a
//! higher motion order tried where neighbours lie on both sides of a frame.

use nalgebra::Vector2;

use crate::adjust::{AdjustConfig, AdjustError, BrownModel, Observation, Problem};
use crate::camera::Term;
use crate::camera::rolling::MotionOrder;

use super::{
    Fit, NestedTest, RollingShutterSetup, Selected, SelectionConfig, SelectionStep, Stage, fit,
    stepwise,
};

/// Tries the rolling-shutter model on top of `best` (intrinsics `terms` free): kept when its
/// motions are significant as a group — the drop of `vᵀPv` over `σ0²` of the trial beyond
/// `χ²(0.999; k)` for its `k` new unknowns (a likelihood-ratio test: no single velocity need
/// be significant) — and it lowers the BIC, whose `k·ln(n)` penalty weighs the six unknowns
/// per frame.
pub(super) fn try_rolling_shutter(
    best: &Fit,
    terms: &[Term],
    setup: RollingShutterSetup,
    adjust: &AdjustConfig,
    log: &dyn Fn(&str),
) -> (SelectionStep, Option<Fit>) {
    let start = best
        .problem
        .with_rolling_shutter(setup.height_px, setup.readout_s);
    let trial = match fit(start, terms, setup.estimate_readout, adjust) {
        Ok(t) => t,
        Err(e) => {
            let reason = format!("adjustment failed: {e}");
            log(&format!("rolling shutter: {reason}"));
            let mut step = SelectionStep::not_tried(&[], best, reason);
            step.rolling_shutter = true;
            return (step, None);
        }
    };
    let k = trial.problem.num_free_parameters() - best.problem.num_free_parameters();
    let test = NestedTest::new(best, &trial, k);
    let NestedTest {
        statistic,
        critical,
        significant,
        ..
    } = test;
    let shear = median_motion_shear_px(&trial.problem);
    let shear_ratio = shear / best.precision.sigma0.max(f64::MIN_POSITIVE);
    log(&format!(
        "rolling shutter: the motions move the rows by {shear:.2} px (median over the frames), {shear_ratio:.1} × the global shutter's σ0"
    ));
    let implausible = !setup.timed && shear_ratio > MAX_SHEAR_OVER_RESIDUAL;
    let accepted = test.accepted() && !implausible;
    let t_values = if setup.estimate_readout {
        let std = trial.precision.global_std();
        vec![trial.problem.global[BrownModel::READOUT] / std[BrownModel::READOUT]]
    } else {
        Vec::new()
    };
    let reason = if accepted {
        "significant, lowers BIC".to_string()
    } else if !significant {
        format!("not significant (χ² {statistic:.1} ≤ {critical:.1} for {k} unknowns)")
    } else if implausible {
        format!(
            "the motions move the rows by {shear:.1} px where the global shutter leaves σ0 {:.3} px ({shear_ratio:.0} × > {MAX_SHEAR_OVER_RESIDUAL}): without neighbouring video frames they stand in for what the frames' geometry does not fix (a flat target field), not for a readout shear",
            best.precision.sigma0
        )
    } else {
        "does not lower BIC".to_string()
    };
    log(&format!(
        "rolling shutter ({k} unknowns{}): χ² {statistic:.1} (critical {critical:.1}), σ0 {:.4} → {:.4} px, BIC {:.1} → {:.1}: {}",
        if setup.estimate_readout {
            format!(
                ", readout {:.2} ms estimated",
                1e3 * trial.problem.global[BrownModel::READOUT]
            )
        } else {
            format!(", readout held at {:.2} ms", 1e3 * setup.readout_s)
        },
        best.precision.sigma0,
        trial.precision.sigma0,
        best.bic,
        trial.bic,
        if accepted {
            format!("kept ({reason})")
        } else {
            format!("refused ({reason})")
        }
    ));
    let step = SelectionStep {
        candidate: Vec::new(),
        rolling_shutter: true,
        accepted,
        t_values,
        bic_before: best.bic,
        bic_after: trial.bic,
        trend_before: best.trend,
        trend_after: Some(trial.trend),
        reason,
    };
    (step, accepted.then_some(trial))
}

/// Without neighbouring video frames, motions whose row displacement is beyond this multiple of
/// what the global-shutter adjustment leaves (its σ0) stand in for something else. A real
/// readout shear is partly absorbed by the pose, so the global shutter keeps a share of it: on
/// the simulated rolling-shutter labs (2–6 °/s) the motions move the rows by 2.6–4.6 × that σ0,
/// on a motionless lab by 6.6 × (and are refused as not significant). Motions along a
/// direction a frame's own geometry does not fix (a flat target field, where a frame
/// determines only a homography) grow without that bound: BoofCV's real dot-grid video, 176 ×,
/// with u0 taken 30–110 px away when they were kept.
pub const MAX_SHEAR_OVER_RESIDUAL: f64 = 50.0;

/// The median over the frames of the displacement (px) their angular rate gives between the
/// middle row and the first or last over half the readout time `(|ω|·τ/2)·c`: what the
/// motions claim the rows were moved by.
#[must_use]
pub fn median_motion_shear_px(problem: &Problem<BrownModel>) -> f64 {
    let half = 0.5
        * problem
            .global
            .get(BrownModel::READOUT)
            .copied()
            .unwrap_or(0.0);
    let c = problem.global[Term::C.index()];
    let mut shear: Vec<f64> = problem
        .motions()
        .iter()
        .map(|m| m.angular.norm() * half * c)
        .collect();
    if shear.is_empty() {
        return 0.0;
    }
    crate::robust::upper_median(&mut shear)
}

/// The readout time of a selected rolling-shutter model estimated with the `extra`
/// observations of its targets in the frames' neighbours in the video (each at its
/// `time_offset_s`): they show how far the frames moved in a known time, which ties the
/// motions to time and separates the readout time from them. They also fix what the frames
/// alone cannot: a roll rate common to all frames shifts columns in proportion to the row
/// and trades with u0 and p2 (`u0 ↔ yaw + p2 + ω_z`), a pan rate and a tilt rate with b2 and
/// b1. The terms stay those selected.
///
/// Over `±1/fps` a hand-held motion is not of constant velocity: its acceleration turns a
/// frame by about a pixel and its jerk makes the neighbours' central difference 1–2 % faster
/// than the velocity the rows see (measured on the simulator's truth,
/// `scripts/neighbour_velocity.py`), and hand tremor at 4–12 Hz bends the path over the
/// `±(1/fps + τ/2)` the three frames' rows span beyond a cubic. The frames' motions are
/// therefore taken to third order here ([`NEIGHBOUR_BASE_MOTION_ORDER`]; each neighbour's own
/// rows show its own velocity, which separates the higher orders from the velocity), for the
/// frames seen from both sides, and to the fourth when its snaps are significant and lower the
/// BIC (`try_higher_motion_order`). What is left (the tremor beyond) can keep the
/// neighbours' residuals larger than the frames'. Their weight is set by a variance-component
/// estimate (`variance_components`), so that σ0 and the covariance stay those of the
/// frames' observations.
///
/// # Errors
/// [`AdjustError::Invalid`] for a model without a rolling shutter or observations that do not
/// fit the problem; [`AdjustError`] when the adjustment cannot run.
pub fn estimate_readout_time(
    selected: Selected,
    extra: &[Observation],
    config: &SelectionConfig,
    adjust: &AdjustConfig,
    log: &dyn Fn(&str),
) -> Result<Selected, AdjustError> {
    let Some(setup) = selected.rolling_shutter else {
        return Err(AdjustError::Invalid(
            "the readout time is estimated only for a rolling-shutter model".into(),
        ));
    };
    // Higher-order motions: over ±1/fps the hand's acceleration turns a frame by about a pixel
    // (the first-order motion left the neighbours 0.9 px RMS off on the 1920 video labs,
    // against the frames' 0.015 px), and its jerk makes the neighbours' central difference
    // 1–2 % faster than the velocity the rows see; both free for the frames with neighbours
    // on both sides.
    let free = frames_with_neighbours_on_both_sides(selected.problem.num_cameras(), extra);
    let mut current = selected
        .problem
        .with_motion_order(NEIGHBOUR_BASE_MOTION_ORDER, &free);
    // The motions start from those selected (fit to the frames alone) or from rest, whichever
    // predicts the neighbours better: within one frame a roll rate common to all frames trades
    // with u0 and p2, and on BoofCV's real video the selected motions put the neighbours
    // 10² to 10⁶ px off (RMS), where at rest they are off by the 9–10 px the hand moved. On
    // the simulated video labs the start is unchanged (the 960 lab's figures to the last
    // digit).
    let at_rest = {
        let mut p = current.clone();
        p.local.fill(0.0);
        p
    };
    let (moving, resting) = (group_rms(&current, extra), group_rms(&at_rest, extra));
    if resting < moving {
        log(&format!(
            "neighbouring video frames: RMS {moving:.3} px at the selected motions, {resting:.3} px at rest: the motions start from rest"
        ));
        current = at_rest;
    }
    // Start from the neighbours' residuals at that start: the weight's fixed point reached
    // from 1 is the compromise where both groups fit equally badly, not the frames'
    // precision. Residuals beyond [`NEIGHBOUR_START_RMS_PX`] are the start's error, not the
    // neighbours': they count as that RMS, so that the neighbours can correct the motions.
    let (frames_start, neighbours_start) = (
        group_rms(&current, &current.observations),
        moving.min(resting),
    );
    log(&format!(
        "neighbouring video frames at the start: RMS {neighbours_start:.3} px against the frames' {frames_start:.4} px"
    ));
    let weight = (frames_start / neighbours_start.clamp(f64::MIN_POSITIVE, NEIGHBOUR_START_RMS_PX))
        .powi(2)
        .min(1.0);
    let (fitted, weight) = variance_components(current, weight, &selected, extra, adjust)?;
    // The fourth order, tried on top like a candidate term.
    let (fitted, weight) =
        match try_higher_motion_order(&fitted, &selected.terms, &free, adjust, log) {
            Some(trial) => variance_components(trial.problem, weight, &selected, extra, adjust)?,
            None => (fitted, weight),
        };
    // The terms the motions hid (a decentring whose p2 a common roll rate could mimic) are
    // tried again now that the neighbours fix the motions.
    let mut steps = selected.steps.clone();
    let (fitted, terms) = stepwise(
        fitted,
        selected.terms.clone(),
        config,
        Stage::WithNeighbours,
        &mut steps,
        adjust,
        log,
    );
    // The neighbours' errors are mostly one motion error per neighbour frame (tremor bends
    // the motion over 1/fps beyond its fourth order), not independent per target: the
    // adjustment's σ of the readout time, which assumes independence, is scaled by the design
    // effect of those clusters (Kish 1965: 1 + (m̄ − 1)·ρ, with the regressor taken as fully
    // correlated within a frame, which is conservative).
    let deff = neighbour_design_effect(&fitted.problem);
    let readout_std_s = fitted.precision.global_std()[BrownModel::READOUT] * deff.sqrt();
    log(&format!(
        "readout time σ scaled by √{deff:.1}: the neighbours' residuals are correlated within each neighbour frame"
    ));
    Ok(Selected {
        terms,
        steps,
        rolling_shutter: Some(RollingShutterSetup {
            estimate_readout: true,
            readout_s: fitted.problem.global[BrownModel::READOUT],
            ..setup
        }),
        problem: fitted.problem,
        precision: fitted.precision,
        summary: fitted.summary,
        bic: fitted.bic,
        readout_std_s: Some(readout_std_s),
        neighbour_weight: Some(weight),
        ..selected
    })
}

/// Adjusts `start` (the frames' observations of `selected` and the neighbours' `extra`) with
/// the neighbours weighted by their variance component (Förstner 1979, simplified to the
/// groups' RMS residuals), `w = (RMS of the frames / RMS of the neighbours)²`, from `weight`
/// and iterated until it changes by less than 10 % (at most
/// [`VARIANCE_COMPONENT_ITERATIONS`] times): the fit and the weight it ended with.
fn variance_components(
    start: Problem<BrownModel>,
    mut weight: f64,
    selected: &Selected,
    extra: &[Observation],
    adjust: &AdjustConfig,
) -> Result<(Fit, f64), AdjustError> {
    let own = selected.problem.observations.len();
    let mut current = start;
    let mut fitted = None;
    for _ in 0..VARIANCE_COMPONENT_ITERATIONS {
        let mut observations = selected.problem.observations.clone();
        observations.extend(extra.iter().map(|o| Observation { weight, ..*o }));
        let mut problem = Problem::new(
            current.model,
            current.cam_from_world.clone(),
            current.local.clone(),
            current.global.clone(),
            current.points.clone(),
            observations,
        )?;
        problem.fixed = current.fixed.clone();
        let fit_now = fit(problem, &selected.terms, true, adjust)?;
        let (frames_rms, neighbours_rms) = (
            group_rms(&fit_now.problem, &fit_now.problem.observations[..own]),
            group_rms(&fit_now.problem, &fit_now.problem.observations[own..]),
        );
        let next = (frames_rms / neighbours_rms.max(f64::MIN_POSITIVE))
            .powi(2)
            .min(1.0);
        current = fit_now.problem.clone();
        fitted = Some(fit_now);
        let settled = (next / weight - 1.0).abs() < 0.1;
        weight = next;
        if settled {
            break;
        }
    }
    fitted
        .map(|f| (f, weight))
        .ok_or_else(|| AdjustError::Invalid("no variance-component iteration ran".into()))
}

/// Tries the frames' motions at [`NEIGHBOUR_MOTION_ORDER`] on top of `best` (at
/// [`NEIGHBOUR_BASE_MOTION_ORDER`], the neighbours at its weight; the snaps free for the frames
/// in `free`), kept like the rolling shutter itself ([`try_rolling_shutter`]) when the new
/// unknowns are significant as a group (`χ²(0.999; k)`) and lower the BIC. Hand tremor at
/// 4–12 Hz bends the path over the `±(1/fps + τ/2)` the three frames' rows span beyond a
/// cubic: on the simulated 4K video labs the fourth order took the camera from 0.06–0.12 px
/// off the truth to 0.013–0.065 px. Whether a real hand needs it is the data's to say.
fn try_higher_motion_order(
    best: &Fit,
    terms: &[Term],
    free: &[bool],
    adjust: &AdjustConfig,
    log: &dyn Fn(&str),
) -> Option<Fit> {
    let start = best.problem.with_motion_order(NEIGHBOUR_MOTION_ORDER, free);
    let k = start.num_free_parameters() - best.problem.num_free_parameters();
    if k == 0 {
        return None;
    }
    let trial = match fit(start, terms, true, adjust) {
        Ok(t) => t,
        Err(e) => {
            log(&format!(
                "{NEIGHBOUR_MOTION_ORDER:?}-order motions: adjustment failed: {e}"
            ));
            return None;
        }
    };
    let test = NestedTest::new(best, &trial, k);
    let NestedTest {
        statistic,
        critical,
        ..
    } = test;
    let verdict = match (test.significant, test.lower_bic) {
        (true, true) => "kept (significant, lowers BIC)".to_string(),
        (false, _) => format!("refused (not significant: χ² ≤ {critical:.1} for {k} unknowns)"),
        (true, false) => "refused (does not lower BIC)".to_string(),
    };
    log(&format!(
        "{NEIGHBOUR_MOTION_ORDER:?}-order motions over the neighbouring video frames ({k} unknowns): χ² {statistic:.1} (critical {critical:.1}), σ0 {:.4} → {:.4} px, BIC {:.1} → {:.1}, readout {:.2} → {:.2} ms: {verdict}",
        best.precision.sigma0,
        trial.precision.sigma0,
        best.bic,
        trial.bic,
        1e3 * best.problem.global[BrownModel::READOUT],
        1e3 * trial.problem.global[BrownModel::READOUT],
    ));
    test.accepted().then_some(trial)
}

/// The order of the frames' motions first adjusted once their neighbours in the video are
/// measured: velocity, acceleration and jerk.
pub const NEIGHBOUR_BASE_MOTION_ORDER: MotionOrder = MotionOrder::Third;

/// The highest order of the frames' motions tried once their neighbours in the video are
/// measured (`try_higher_motion_order`): the fourth, the highest at which a frame and its
/// two neighbours still determine the readout time ([`MotionOrder::Fourth`]). On the 4K video
/// labs' exact rolling-shutter projections (`examples/video_truth_adjust.rs`, seed 1) the
/// third order left the camera 0.062–0.139 px off the truth (the tremor it cannot follow), the
/// fourth 0.011–0.024 px.
pub const NEIGHBOUR_MOTION_ORDER: MotionOrder = MotionOrder::Fourth;

/// Neighbour observations a frame needs on each side (before and after it) for its
/// higher-order motion to be adjusted: seen as the curvature of its path through the three
/// times and the rows of the neighbours.
pub const MIN_NEIGHBOUR_OBSERVATIONS_PER_SIDE: usize = 4;

/// Per camera of `n_cameras`, whether the neighbour observations `extra` see it from both
/// sides, at least [`MIN_NEIGHBOUR_OBSERVATIONS_PER_SIDE`] on each.
fn frames_with_neighbours_on_both_sides(n_cameras: usize, extra: &[Observation]) -> Vec<bool> {
    let mut counts = vec![(0usize, 0usize); n_cameras];
    for o in extra {
        if let Some(c) = counts.get_mut(o.camera) {
            if o.time_offset_s < 0.0 {
                c.0 += 1;
            } else if o.time_offset_s > 0.0 {
                c.1 += 1;
            }
        }
    }
    counts
        .into_iter()
        .map(|(before, after)| {
            before >= MIN_NEIGHBOUR_OBSERVATIONS_PER_SIDE
                && after >= MIN_NEIGHBOUR_OBSERVATIONS_PER_SIDE
        })
        .collect()
}

/// The design effect `1 + (m̄ − 1)·ρ` of the neighbour observations (`time_offset_s ≠ 0`)
/// clustered by neighbour frame (camera and side): ρ the intra-cluster correlation of their
/// residuals (one-way analysis of variance, u and v pooled, clamped to [0, 1]), m̄ the mean
/// cluster size. 1 without neighbours or with fewer than two clusters.
fn neighbour_design_effect(problem: &Problem<BrownModel>) -> f64 {
    let mut clusters: std::collections::BTreeMap<(usize, bool), Vec<Vector2<f64>>> =
        std::collections::BTreeMap::new();
    for o in &problem.observations {
        if o.time_offset_s != 0.0
            && let Some(r) = problem.residual(o)
        {
            clusters
                .entry((o.camera, o.time_offset_s > 0.0))
                .or_default()
                .push(r);
        }
    }
    let clusters: Vec<Vec<Vector2<f64>>> = clusters.into_values().collect();
    design_effect(&clusters)
}

/// Kish's design effect `1 + (m̄ − 1)·ρ` of 2-D residuals in `clusters` (those of fewer than two
/// left out); 1 with fewer than two clusters.
fn design_effect(clusters: &[Vec<Vector2<f64>>]) -> f64 {
    let clusters: Vec<&Vec<Vector2<f64>>> = clusters.iter().filter(|c| c.len() >= 2).collect();
    if clusters.len() < 2 {
        return 1.0;
    }
    let n: usize = clusters.iter().map(|c| c.len()).sum();
    let k = clusters.len();
    let mean_size = n as f64 / k as f64;
    let grand = clusters.iter().copied().flatten().sum::<Vector2<f64>>() / n as f64;
    // Between- and within-cluster mean squares, per coordinate, pooled over u and v.
    let (mut ss_between, mut ss_within) = (0.0, 0.0);
    for c in clusters {
        let mean = c.iter().sum::<Vector2<f64>>() / c.len() as f64;
        ss_between += c.len() as f64 * (mean - grand).norm_squared();
        ss_within += c.iter().map(|r| (r - mean).norm_squared()).sum::<f64>();
    }
    let ms_between = ss_between / (2.0 * (k - 1) as f64);
    let ms_within = ss_within / (2.0 * (n - k) as f64).max(1.0);
    let between = ((ms_between - ms_within) / mean_size).max(0.0);
    let rho = if between + ms_within > 0.0 {
        (between / (between + ms_within)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    1.0 + (mean_size - 1.0) * rho
}

/// RMS residual per coordinate of `observations` in `problem` (px).
fn group_rms(problem: &Problem<BrownModel>, observations: &[Observation]) -> f64 {
    let (sum, n) = observations
        .iter()
        .filter_map(|o| problem.residual(o))
        .fold((0.0, 0usize), |(s, n), r| (s + r.norm_squared(), n + 1));
    (sum / (2 * n.max(1)) as f64).sqrt()
}

/// Largest RMS residual (px) of the neighbouring video frames that sets their first weight
/// ([`estimate_readout_time`]). A first-order motion carried over `±1/fps` misses by the hand's
/// tremor over that time, a fraction of a pixel on the simulated labs. On BoofCV's real video
/// the motions selected from one frame's rows (where a roll rate common to all frames trades
/// with u0 and p2) missed the neighbours by 10² to 10⁶ px, and at rest they miss by the 9–10 px
/// the hand moved; weighted by that, the neighbours could not correct the motions.
pub const NEIGHBOUR_START_RMS_PX: f64 = 1.0;

/// Most adjustments of the neighbours' variance component ([`estimate_readout_time`]).
pub const VARIANCE_COMPONENT_ITERATIONS: usize = 4;

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame's higher-order motion is free only with enough neighbour observations before
    /// and after it.
    #[test]
    fn higher_order_motion_needs_neighbours_on_both_sides() {
        let at = |camera: usize, offset: f64| Observation {
            time_offset_s: offset,
            ..Observation::new(camera, 0, Vector2::zeros())
        };
        let n = MIN_NEIGHBOUR_OBSERVATIONS_PER_SIDE;
        let mut extra = Vec::new();
        // Camera 0: n before and n after; camera 1: n after only; camera 2: n − 1 before.
        extra.extend((0..n).flat_map(|_| [at(0, -0.04), at(0, 0.04), at(1, 0.04)]));
        extra.extend((0..n).map(|_| at(2, 0.04)));
        extra.extend((1..n).map(|_| at(2, -0.04)));
        // Own-frame observations and an unknown camera count for nothing.
        extra.extend((0..n).map(|_| at(1, 0.0)));
        extra.push(at(7, -0.04));
        assert_eq!(
            frames_with_neighbours_on_both_sides(3, &extra),
            vec![true, false, false]
        );
    }
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_design_effect_counts_a_common_error_per_cluster_once() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut noise = || Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        // Clusters of 20: independent noise gives about 1; one error per cluster and nothing
        // of its own gives m = 20 exactly; a common error as large as the own noise gives
        // ρ = 1/2 and 1 + 19/2 = 10.5.
        let independent: Vec<Vec<Vector2<f64>>> = (0..50)
            .map(|_| (0..20).map(|_| noise()).collect())
            .collect();
        let common: Vec<Vec<Vector2<f64>>> = (0..50).map(|_| vec![noise(); 20]).collect();
        let half: Vec<Vec<Vector2<f64>>> = (0..400)
            .map(|_| {
                let e = noise();
                (0..20).map(|_| e + noise()).collect()
            })
            .collect();
        let d = design_effect(&independent);
        assert!((0.5..=1.6).contains(&d), "{d}");
        assert!((design_effect(&common) - 20.0).abs() < 1e-9);
        let d = design_effect(&half);
        assert!((d - 10.5).abs() < 1.5, "{d}");
        assert_eq!(design_effect(&common[..1]), 1.0);
    }
}
