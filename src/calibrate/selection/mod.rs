//! Stepwise selection of the distortion terms (paper, "Selection of Terms for Radial Lens
//! Distortion", after Lichti et al. 2020).
//!
//! Start with the principal distance and the principal point only (c, u0, v0); then add one
//! candidate at a time — k1, k2, k3, then the decentring pair (p1, p2) and the affinity pair
//! (b1, b2) — re-adjusting the free network each time. A candidate is kept when
//!
//! 1. its estimate is significant: `|x̂ / σ_x̂| > t_critical` (for a pair, either member);
//! 2. it lowers the Bayesian information criterion `BIC = n·ln(vᵀPv / n) + k·ln(n)` (n
//!    observed coordinates, k unknowns). BIC rather than AIC: with thousands of observations
//!    AIC's penalty of 2 per parameter lets noise-level terms in; BIC's ln(n) ≈ 9 does not;
//!
//! and the radial terms go on only while the radial residuals keep a systematic trend: they
//! stop as soon as no trend remains or a radial term is refused. The trend test compares the
//! mean radial residual in 24 bins of the radius with zero (an F-ratio against the scatter
//! within the bins, critical value χ²(0.99; 24)/24 = 1.79): any shape, since a missing k3 leaves
//! a residual that a low-order polynomial in the radius does not see (measured on the S10
//! preset). It is a stopping rule, not an acceptance test for each term: radial terms are
//! strongly correlated, and k1 alone can leave a higher-order trend as large as before
//! (P30 preset: 0.030 → 0.031 px RMS while σ0 halves), which k2 then removes.

use nalgebra::Vector2;
use serde::Serialize;

use crate::adjust::{
    AdjustConfig, AdjustError, AdjustSummary, BrownModel, Precision, PrecisionRequest, Problem,
    bundle_adjust, precision,
};
use crate::camera::Term;

mod rolling_shutter;

use rolling_shutter::try_rolling_shutter;
pub use rolling_shutter::{
    MAX_SHEAR_OVER_RESIDUAL, MIN_NEIGHBOUR_OBSERVATIONS_PER_SIDE, NEIGHBOUR_BASE_MOTION_ORDER,
    NEIGHBOUR_MOTION_ORDER, NEIGHBOUR_START_RMS_PX, VARIANCE_COMPONENT_ITERATIONS,
    estimate_readout_time, median_motion_shear_px,
};

/// One candidate of the selection.
#[derive(Clone, Debug, PartialEq)]
pub enum Candidate {
    /// A group of intrinsics added as a whole.
    Terms(Vec<Term>),
    /// The rolling-shutter model ([`crate::camera::rolling`]): a motion `(ω, ν)` per frame
    /// (6 values) and the readout time, estimated when the frames' neighbours say how fast
    /// the camera moved, else held at its given value ([`RollingShutterSetup`]). Tried only
    /// when [`SelectionConfig::rolling_shutter`] is set.
    RollingShutter,
}

/// What the rolling-shutter candidate starts from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RollingShutterSetup {
    /// Frame height (px): rows → times.
    pub height_px: f64,
    /// Readout time to start from, or to hold (s).
    pub readout_s: f64,
    /// Estimate the readout time: only when observations in neighbouring video frames
    /// (`time_offset_s ≠ 0`) tie the frames' motion to time; with one frame per instant only
    /// the products readout × velocity show in the image.
    pub estimate_readout: bool,
    /// Whether the frames' neighbours in the video will tie the motions to time. Without them
    /// the motions are refused when they move the rows far more than the global shutter's
    /// residuals allow ([`MAX_SHEAR_OVER_RESIDUAL`]).
    pub timed: bool,
}

/// How terms are selected.
#[derive(Clone, Debug, PartialEq)]
pub struct SelectionConfig {
    /// Candidates in the order they are tried.
    pub candidates: Vec<Candidate>,
    /// Critical |t| of a significant term (3.29: two-sided 0.1 %).
    pub t_critical: f64,
    /// Critical F of a remaining radial trend ([`TREND_CRITICAL`]).
    pub trend_critical: f64,
    /// The rolling-shutter candidate's setup; `None` (default) leaves it out.
    pub rolling_shutter: Option<RollingShutterSetup>,
}

impl Default for SelectionConfig {
    /// The radial terms, then p1+p2 and b1+b2; the rolling shutter is tried after them
    /// ([`select_terms`]).
    fn default() -> Self {
        SelectionConfig {
            candidates: vec![
                Candidate::Terms(vec![Term::K1]),
                Candidate::Terms(vec![Term::K2]),
                Candidate::Terms(vec![Term::K3]),
                Candidate::Terms(vec![Term::P1, Term::P2]),
                Candidate::Terms(vec![Term::B1, Term::B2]),
                Candidate::RollingShutter,
            ],
            t_critical: 3.29,
            trend_critical: TREND_CRITICAL,
            rolling_shutter: None,
        }
    }
}

/// `z` of the one-sided 0.999 normal quantile.
const Z_999: f64 = 3.090_232;

/// `χ²(0.999; k)` by the Wilson–Hilferty approximation (good to a fraction of a percent for
/// the hundreds of degrees of freedom of a video's motions).
#[must_use]
pub fn chi2_999(k: usize) -> f64 {
    let k = k.max(1) as f64;
    let h = 2.0 / (9.0 * k);
    k * (1.0 - h + Z_999 * h.sqrt()).powi(3)
}

/// One decision of the selection, for the log and the report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SelectionStep {
    /// The candidate tried (its terms; empty for the rolling shutter).
    pub candidate: Vec<Term>,
    /// Whether the candidate was the rolling-shutter model.
    pub rolling_shutter: bool,
    /// Whether it was kept.
    pub accepted: bool,
    /// t-values of its estimates (empty when it was not tried).
    pub t_values: Vec<f64>,
    /// BIC before and with the candidate.
    pub bic_before: f64,
    /// BIC with the candidate (NaN when not tried).
    pub bic_after: f64,
    /// Radial trend before the candidate.
    pub trend_before: RadialTrend,
    /// Radial trend with the candidate (`None` when not tried).
    pub trend_after: Option<RadialTrend>,
    /// Why, in words.
    pub reason: String,
}

impl SelectionStep {
    /// A candidate refused without an adjustment of its own (or whose adjustment failed).
    fn not_tried(candidate: &[Term], best: &Fit, reason: String) -> Self {
        SelectionStep {
            candidate: candidate.to_vec(),
            rolling_shutter: false,
            accepted: false,
            t_values: Vec::new(),
            bic_before: best.bic,
            bic_after: f64::NAN,
            trend_before: best.trend,
            trend_after: None,
            reason,
        }
    }
}

/// Statistics of one adjusted model.
#[derive(Clone, Debug)]
struct Fit {
    problem: Problem<BrownModel>,
    summary: AdjustSummary,
    precision: Precision,
    bic: f64,
    trend: RadialTrend,
}

/// The outcome of the selection.
#[derive(Clone, Debug)]
pub struct Selected {
    /// The adjusted problem with the chosen terms free.
    pub problem: Problem<BrownModel>,
    /// The terms estimated (c, u0, v0 and the kept candidates).
    pub terms: Vec<Term>,
    /// Its precision.
    pub precision: Precision,
    /// Its solver summary.
    pub summary: AdjustSummary,
    /// Every decision, in order.
    pub steps: Vec<SelectionStep>,
    /// Radial residuals `(r_px, v_r_px)` of the model with c, u0, v0 only.
    pub radial_base: Vec<(f64, f64)>,
    /// Bayesian information criterion of the chosen model (module docs).
    pub bic: f64,
    /// The rolling-shutter model, when it was kept (the problem's model then has it).
    pub rolling_shutter: Option<RollingShutterSetup>,
    /// σ of the readout time estimated from the neighbouring video frames
    /// ([`estimate_readout_time`]), s; `None` when it was held.
    pub readout_std_s: Option<f64>,
    /// Weight of the observations in the neighbouring video frames relative to the frames'
    /// (their variance component, [`estimate_readout_time`]); `None` without them.
    pub neighbour_weight: Option<f64>,
}

impl Selected {
    /// The model chosen.
    #[must_use]
    pub fn choice(&self) -> ModelChoice {
        ModelChoice {
            terms: self.terms.clone(),
            rolling_shutter: self.rolling_shutter.is_some(),
        }
    }
}

/// A model the selection can end with: its intrinsics and whether the rolling shutter is in.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ModelChoice {
    /// The intrinsics estimated.
    pub terms: Vec<Term>,
    /// Whether the frames' readout motion is modelled.
    pub rolling_shutter: bool,
}

impl std::fmt::Display for ModelChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&names_list(&self.terms, ", "))?;
        if self.rolling_shutter {
            f.write_str(", rolling shutter")?;
        }
        Ok(())
    }
}

/// Radial residuals `(r, v_r)` in pixels of an adjusted `brown` problem: the component of
/// `measured − projected` along the direction from the principal point.
#[must_use]
pub fn radial_residuals(problem: &Problem<BrownModel>) -> Vec<(f64, f64)> {
    let (u0, v0) = (problem.global[1], problem.global[2]);
    problem
        .observations
        .iter()
        .filter(|o| o.weight > 0.0)
        .filter_map(|o| {
            let res = -problem.residual(o)?;
            let d = o.uv - Vector2::new(u0, v0);
            let r = d.norm();
            (r > 0.0).then(|| (r, res.dot(&d) / r))
        })
        .collect()
}

/// Bins of the radial trend test.
pub const TREND_BINS: usize = 24;
/// `χ²(0.99; 24) / 24`: the F-ratio above which a radial trend remains.
pub const TREND_CRITICAL: f64 = 42.98 / 24.0;

/// The systematic part of radial residuals: their mean in [`TREND_BINS`] equal bins of the
/// radius.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RadialTrend {
    /// F-ratio of the bin means against zero: `Σ n_b·m_b² / σ̂² / B`, σ̂² the pooled variance
    /// within the bins; a trend remains above `χ²(0.99; B)/B`.
    pub f: f64,
    /// RMS of the bin means over the samples (px): how much systematic error remains.
    pub rms_px: f64,
}

/// Tests `(r, v_r)` samples for a radial trend: any shape of mean against the radius, not a
/// fixed polynomial (a missing k3 leaves a residual the low-order terms' fit cannot see).
#[must_use]
pub fn radial_trend(samples: &[(f64, f64)]) -> RadialTrend {
    let none = RadialTrend {
        f: 0.0,
        rms_px: 0.0,
    };
    let n = samples.len();
    if n < 4 * TREND_BINS {
        return none;
    }
    let r_max = samples.iter().map(|s| s.0).fold(0.0, f64::max);
    if r_max <= 0.0 {
        return none;
    }
    let mut sum = [0.0; TREND_BINS];
    let mut sum2 = [0.0; TREND_BINS];
    let mut count = [0usize; TREND_BINS];
    for &(r, v) in samples {
        let k = ((r / r_max) * TREND_BINS as f64)
            .floor()
            .clamp(0.0, (TREND_BINS - 1) as f64) as usize;
        sum[k] += v;
        sum2[k] += v * v;
        count[k] += 1;
    }
    let (mut between, mut within, mut bins) = (0.0, 0.0, 0usize);
    for k in 0..TREND_BINS {
        if count[k] == 0 {
            continue;
        }
        let m = sum[k] / count[k] as f64;
        between += count[k] as f64 * m * m;
        within += sum2[k] - count[k] as f64 * m * m;
        bins += 1;
    }
    let dof = n.saturating_sub(bins).max(1);
    let var = within / dof as f64;
    RadialTrend {
        f: if var > 0.0 {
            between / var / bins as f64
        } else {
            f64::INFINITY
        },
        rms_px: (between / n as f64).sqrt(),
    }
}

/// Adjusts `problem` with the intrinsics `free` (the others fixed); a rolling-shutter
/// problem's motions are free and its readout time free when `readout_free`.
fn fit(
    mut problem: Problem<BrownModel>,
    free: &[Term],
    readout_free: bool,
    adjust: &AdjustConfig,
) -> Result<Fit, AdjustError> {
    problem.fixed.global = Term::ALL
        .iter()
        .filter(|t| !free.contains(t))
        .map(|t| t.index())
        .collect();
    if problem.model.rolling_shutter.is_some() && !readout_free {
        problem.fixed.global.push(BrownModel::READOUT);
    }
    let summary = bundle_adjust(&mut problem, adjust)?;
    let precision = precision(&problem, PrecisionRequest::default())?;
    let n = 2.0 * precision.observations as f64;
    let vtpv = precision.sigma0.powi(2) * precision.redundancy as f64;
    let k = problem.num_free_parameters() as f64 - 7.0;
    let bic = n * (vtpv / n).ln() + k * n.ln();
    let trend = radial_trend(&radial_residuals(&problem));
    Ok(Fit {
        problem,
        summary,
        precision,
        bic,
        trend,
    })
}

/// Runs the stepwise selection from `problem` (its distortion terms are reset to zero first;
/// a rolling-shutter problem starts without its motions).
///
/// The intrinsics are selected first with a global shutter. The rolling shutter, when
/// [`SelectionConfig::rolling_shutter`] is set and [`Candidate::RollingShutter`] is a
/// candidate, is then tried on top of them; when it is kept, every term is selected again
/// from c, u0, v0 with the motions in the model. Tried earlier, the motions would take up
/// what decentring and affinity terms not yet chosen leave (a roll rate common to the frames
/// mimics p2 with u0; a pan or tilt rate b2 or b1): on a motionless lab they lowered σ0 by a
/// sixth before p1, p2 were in. Tried later without the second pass, the terms chosen under
/// the motions' residuals (no radial trend visible under 0.5 px of shear, b1 and b2 taking
/// part of it) would stay.
///
/// # Errors
/// [`AdjustError`] when even the base model (c, u0, v0) cannot be adjusted.
pub fn select_terms(
    problem: &Problem<BrownModel>,
    config: &SelectionConfig,
    adjust: &AdjustConfig,
    log: &dyn Fn(&str),
) -> Result<Selected, AdjustError> {
    let mut start = problem.without_rolling_shutter();
    for t in &Term::ALL[3..] {
        start.global[t.index()] = 0.0;
    }
    let base_terms = vec![Term::C, Term::U0, Term::V0];
    let base = fit(start, &base_terms, false, adjust)?;
    let radial_base = radial_residuals(&base.problem);
    let mut steps = Vec::new();
    let (mut best, mut terms) = stepwise(
        base,
        base_terms.clone(),
        config,
        Stage::GlobalShutter,
        &mut steps,
        adjust,
        log,
    );
    let mut rolling = None;
    if let Some(setup) = config.rolling_shutter
        && config.candidates.contains(&Candidate::RollingShutter)
    {
        let (step, kept) = try_rolling_shutter(&best, &terms, setup, adjust, log);
        steps.push(step);
        if let Some(trial) = kept {
            log("rolling shutter kept: the terms are selected again with it");
            let mut start = trial.problem;
            for t in &Term::ALL[3..] {
                start.global[t.index()] = 0.0;
            }
            let base = fit(start, &base_terms, false, adjust)?;
            (best, terms) = stepwise(
                base,
                base_terms,
                config,
                Stage::RollingShutter,
                &mut steps,
                adjust,
                log,
            );
            rolling = Some(setup);
        }
    }
    Ok(Selected {
        problem: best.problem,
        terms,
        precision: best.precision,
        summary: best.summary,
        steps,
        radial_base,
        bic: best.bic,
        rolling_shutter: rolling,
        readout_std_s: None,
        neighbour_weight: None,
    })
}

/// What the model of a stepwise pass has besides the intrinsics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    /// A global shutter.
    GlobalShutter,
    /// The frames' motions, the readout time held.
    RollingShutter,
    /// The motions, the neighbours' observations and the readout time free.
    WithNeighbours,
}

/// The forward stepwise selection of the intrinsic candidates of `config` not yet in `terms`
/// from `best` (its `terms` free), each kept when significant and lowering the BIC; the
/// decisions are appended to `steps`.
fn stepwise(
    mut best: Fit,
    mut terms: Vec<Term>,
    config: &SelectionConfig,
    stage: Stage,
    steps: &mut Vec<SelectionStep>,
    adjust: &AdjustConfig,
    log: &dyn Fn(&str),
) -> (Fit, Vec<Term>) {
    log(&format!(
        "terms {}{}: σ0 {:.4} px, BIC {:.1}, radial trend {:.4} px (F {:.1})",
        names_list(&terms, ", "),
        match stage {
            Stage::GlobalShutter => "",
            Stage::RollingShutter => " and the rolling shutter",
            Stage::WithNeighbours => {
                " and the rolling shutter with the neighbouring video frames"
            }
        },
        best.precision.sigma0,
        best.bic,
        best.trend.rms_px,
        best.trend.f
    ));
    let mut radial_done = false;
    for candidate in &config.candidates {
        let Candidate::Terms(group) = candidate else {
            continue;
        };
        if group.iter().all(|t| terms.contains(t)) {
            continue;
        }
        let radial = is_radial(group);
        if radial && radial_done {
            continue;
        }
        if radial && best.trend.f <= config.trend_critical {
            let reason = format!(
                "no radial trend remains (F {:.2} ≤ {:.2}): radial terms stop",
                best.trend.f, config.trend_critical
            );
            log(&format!("{}: {reason}", names(group)));
            steps.push(SelectionStep::not_tried(group, &best, reason));
            radial_done = true;
            continue;
        }
        let mut trial_terms = terms.clone();
        trial_terms.extend(group.iter().copied());
        // The readout time is held without the neighbours (one frame per instant shows only
        // the products readout × velocity).
        let readout_free = stage == Stage::WithNeighbours;
        let trial = match fit(best.problem.clone(), &trial_terms, readout_free, adjust) {
            Ok(t) => t,
            Err(e) => {
                let reason = format!("adjustment failed: {e}");
                log(&format!("{}: {reason}", names(group)));
                steps.push(SelectionStep::not_tried(group, &best, reason));
                radial_done |= radial;
                continue;
            }
        };
        let std = trial.precision.global_std();
        let t_values: Vec<f64> = group
            .iter()
            .map(|t| trial.problem.global[t.index()] / std[t.index()])
            .collect();
        let significant = t_values.iter().any(|t| t.abs() > config.t_critical);
        let lower_bic = trial.bic < best.bic;
        let accepted = significant && lower_bic;
        let reason = if accepted {
            "significant, lowers BIC".to_string()
        } else if !significant {
            format!("not significant (|t| ≤ {:.2})", config.t_critical)
        } else {
            "does not lower BIC".to_string()
        };
        log(&format!(
            "{}: t = {}, BIC {:.1} → {:.1}, radial trend {:.4} → {:.4} px: {}",
            names(group),
            t_values
                .iter()
                .map(|t| format!("{t:.1}"))
                .collect::<Vec<_>>()
                .join(", "),
            best.bic,
            trial.bic,
            best.trend.rms_px,
            trial.trend.rms_px,
            if accepted {
                format!("kept ({reason})")
            } else {
                format!("refused ({reason})")
            }
        ));
        steps.push(SelectionStep {
            candidate: group.clone(),
            rolling_shutter: false,
            accepted,
            t_values,
            bic_before: best.bic,
            bic_after: trial.bic,
            trend_before: best.trend,
            trend_after: Some(trial.trend),
            reason,
        });
        if accepted {
            terms = trial_terms;
            best = trial;
        } else if radial {
            radial_done = true;
        }
    }
    (best, terms)
}

/// The likelihood-ratio test and BIC comparison of a nested `trial` against `best`, `k`
/// unknowns more: the drop of `vᵀPv` over the trial's `σ0²` against `χ²(0.999; k)`.
struct NestedTest {
    statistic: f64,
    critical: f64,
    significant: bool,
    lower_bic: bool,
}

impl NestedTest {
    fn new(best: &Fit, trial: &Fit, k: usize) -> Self {
        let vtpv = |f: &Fit| f.precision.sigma0.powi(2) * f.precision.redundancy as f64;
        let statistic = (vtpv(best) - vtpv(trial)) / trial.precision.sigma0.powi(2).max(1e-300);
        let critical = chi2_999(k);
        NestedTest {
            statistic,
            critical,
            significant: statistic > critical,
            lower_bic: trial.bic < best.bic,
        }
    }

    /// Kept: significant and lowering the BIC.
    fn accepted(&self) -> bool {
        self.significant && self.lower_bic
    }
}

/// Adjusts `problem` with the model `choice` and no selection (the other intrinsics reset to
/// zero and fixed; the rolling shutter of `setup` when the choice has it): the calibration
/// loop's model once the selection alternated between two ([`super::pipeline`]).
///
/// # Errors
/// [`AdjustError`] when either the base model (c, u0, v0, for the radial residuals of the
/// report) or the chosen model cannot be adjusted, or [`AdjustError::Invalid`] for a choice
/// with a rolling shutter and no `setup`.
pub fn adjust_terms(
    problem: &Problem<BrownModel>,
    choice: &ModelChoice,
    setup: Option<RollingShutterSetup>,
    adjust: &AdjustConfig,
) -> Result<Selected, AdjustError> {
    let terms = &choice.terms;
    let rolling = if choice.rolling_shutter {
        Some(setup.ok_or_else(|| {
            AdjustError::Invalid("a rolling-shutter model needs its setup".into())
        })?)
    } else {
        None
    };
    let mut start = match rolling {
        Some(_) if problem.model.rolling_shutter.is_some() => problem.clone(),
        Some(r) => problem.with_rolling_shutter(r.height_px, r.readout_s),
        None => problem.without_rolling_shutter(),
    };
    let mut bare = problem.without_rolling_shutter();
    for t in &Term::ALL[3..] {
        bare.global[t.index()] = 0.0;
        if !terms.contains(t) {
            start.global[t.index()] = 0.0;
        }
    }
    let base = fit(bare, &[Term::C, Term::U0, Term::V0], false, adjust)?;
    let chosen = fit(
        start,
        terms,
        rolling.is_some_and(|r| r.estimate_readout),
        adjust,
    )?;
    Ok(Selected {
        problem: chosen.problem,
        terms: terms.to_vec(),
        precision: chosen.precision,
        summary: chosen.summary,
        steps: Vec::new(),
        radial_base: radial_residuals(&base.problem),
        bic: chosen.bic,
        rolling_shutter: rolling,
        readout_std_s: None,
        neighbour_weight: None,
    })
}

/// A group of radial terms only.
fn is_radial(group: &[Term]) -> bool {
    group
        .iter()
        .all(|t| matches!(t, Term::K1 | Term::K2 | Term::K3))
}

fn names(terms: &[Term]) -> String {
    names_list(terms, "+")
}

fn names_list(terms: &[Term], separator: &str) -> String {
    terms
        .iter()
        .map(|t| t.name())
        .collect::<Vec<_>>()
        .join(separator)
}
