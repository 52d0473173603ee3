//! Detection of circular targets and their best-fit ellipses (layer 2), paper step (3):
//! "Automated Ellipse Detection from Images", in the spirit of Maalek & Lichti 2020a (robust to
//! false detections and misses) and 2020b (precise geometric fits).
//!
//! frame → grey (8-bit luma) → Sobel gradients and an Immerkær noise estimate → Canny edges
//! (non-maximum suppression, hysteresis thresholds at 6 and 12 noise σ of the gradient), at full
//! and at half resolution (where a blurred edge several px wide holds together) → chains of edge
//! pixels with agreeing gradients → arcs split at corners and inflections → candidate ellipses
//! from arcs that turn ≥ 80° and fit an ellipse (arcs proposing the same ellipse are grouped) →
//! sub-pixel edge points along the normals of each candidate (a window of ±2.5 edge widths) and
//! a robust geometric fit, repeated until it settles; the centre's σ from the fit with the
//! correlation of neighbouring edge points (they share pixels) → validation ([`step`]): edge
//! support all round (≥ 90 % of the normals), one polarity, a fit residual without the
//! harmonics a non-ellipse has, and grey levels that are a printed disc: a blurred step between
//! two flat levels across the edge, levels several-fold apart (ink on paper), a uniform
//! interior, a uniform surround, a disc resolved against its blur; size and axis-ratio limits,
//! fully inside the frame → overlapping detections resolved (the better supported one stays).
//!
//! Works on black discs on white and white discs on black alike; a target cut by the frame or
//! occluded loses support on part of its edge and is rejected rather than fitted badly.

pub mod contours;
pub mod edges;
pub mod fit;
pub mod image;
pub mod refine;
pub mod step;

use serde::{Deserialize, Serialize};

use self::image::GrayImage;
use crate::geometry::conic::Ellipse;

/// The smallest semi-minor axis (px) of a target used to measure (calibration, matching, the
/// site's scale): the default of the commands' `--min-semi-minor` and of the experiments that
/// stand for them. Smaller ellipses are still detected (down to
/// [`DetectConfig::min_semi_minor_px`]) but their centres carry too little edge to trust.
pub const MIN_SEMI_MINOR_TO_MEASURE_PX: f64 = 4.0;

/// The fit residual (px) allowed per px of edge width (the σ of its blur), where that exceeds
/// [`DetectConfig::max_rms_px`]: a defocused edge is located to a fraction of its width, and
/// what lies within its widened window (a plate's border, the surround's texture) moves the
/// edge points by more than a sharp edge's 0.25 px. The shape test (harmonics 3–6 at most
/// [`DetectConfig::max_shape_deviation`] of b) still refuses what is no ellipse, and the
/// centre's σ, from the residuals, grows with them. Simulated lab targets blurred by σ 4 px
/// (edge width 2.6–3.3 px as fitted beside their plates) show 0.27–0.40 px.
const RMS_PER_EDGE_WIDTH: f64 = 0.15;

/// The smallest semi-minor axis (px) detected by default: BoofCV's hand-held videos show dots
/// down to 2.4 px, all found at this size with their centres' σ honest.
pub const MIN_SEMI_MINOR_PX: f64 = 2.0;

/// Detection options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectConfig {
    /// Smallest semi-minor axis reported (px), default [`MIN_SEMI_MINOR_PX`] (the centre's σ
    /// says how weak a small target is: [`DetectedEllipse::centre_std_px`]).
    pub min_semi_minor_px: f64,
    /// Largest semi-major axis as a fraction of the smaller image side, default 0.25.
    pub max_semi_major_fraction: f64,
    /// Smallest axis ratio b/a (more oblique views are unreliable), default 0.15.
    pub min_axis_ratio: f64,
    /// Least distance of the ellipse from the frame border (px), default 2.
    pub border_margin_px: f64,
    /// Fraction of the normals that must show the edge, default 0.9.
    pub min_support: f64,
    /// Largest RMS of the orthogonal fit residuals (px), default 0.25 (sharp stills: ≤ 0.13;
    /// dots of 5–14 px in BoofCV's hand-held H.264 video: up to 0.17); edges wider than
    /// 1.67 px (defocus) are allowed 0.15 px per px of width.
    pub max_rms_px: f64,
    /// Largest amplitude of the edge residuals' harmonics 3–6 (which no ellipse has) as a
    /// fraction of the semi-minor axis, default 0.08: a sector of a coded target's ring (a
    /// curved box with four corners) reaches 0.13 once it is 4 px wide; dots of real stills stay
    /// below 0.02, small dots of H.264 video (squared by its 8×8 blocks) below 0.065.
    pub max_shape_deviation: f64,
    /// Least grey-level difference between inside and outside, default 50: BoofCV's printed dots
    /// show 86–208 in its stills and video; the specks, knots and pebbles around them that pass
    /// every shape test mostly 25–46.
    pub min_contrast: f64,
    /// Smallest semi-minor axis in edge widths (`b / w`, the width the σ of the edge's blur),
    /// default 2: a disc narrower than that is an unresolved spot, whose shape no test can tell.
    pub min_resolution: f64,
    /// Largest RMS of the grey levels inside the disc (deeper than two edge widths and 1.5 px)
    /// about a plane, as a fraction of the contrast (plus two noise σ), default 0.15: a printed
    /// disc is flat (BoofCV's dots: ≤ 0.04 in the stills, ≤ 0.08 in the H.264 video); the centre
    /// dot inside an arc of a coded target's ring (≈ 0.4) is not.
    pub max_interior_spread: f64,
    /// Largest spread of the surround's level just outside the edge (from two edge widths
    /// beyond it, where the surround shows: see [`step`]), as a fraction of the contrast (plus
    /// two noise σ), default 0.15: the paper around printed dots stays below 0.1, even between
    /// the dots of BoofCV's dense hexagonal grid.
    pub max_ring_spread: f64,
    /// Largest RMS of the median edge profile about the fitted blurred step, as a fraction of
    /// the contrast, default 0.1 (real dots: ≤ 0.06): a shaded dome (a screw head, a rivet) is
    /// no step between two flat levels.
    pub max_step_residual: f64,
    /// Largest ratio of the fitted step's darker level to its lighter one, default
    /// [`MAX_LEVEL_RATIO`]: a target is ink on paper (or paper on ink), and the two differ
    /// several-fold even in gamma-encoded grey levels; the blotches, stains and shadows of a
    /// wall that pass every shape test differ from the wall around them by far less. Judged
    /// only on a disc with an interior (deeper than two edge widths and 1.5 px, where
    /// [`DetectedEllipse::interior_spread`] is measured): a smaller or more blurred disc never
    /// shows its levels, and the step's fitted levels are then an extrapolation.
    pub max_level_ratio: f64,
    /// Only discs of this polarity (`None`: both), default `None`. A calibration grid of black
    /// dots is found with `Some(Dark)`, as OpenCV's blob detector does by default; white things
    /// round enough to pass every appearance test (pins, pebbles) then go too.
    pub polarity: Option<DiscPolarity>,
    /// Canny's low threshold in noise σ of the Sobel response (the high one is twice it),
    /// default 6.
    pub threshold_sigma: f64,
    /// Across a set of frames detected together, discs of the polarity that makes up at most
    /// this share of the detections are dropped as the stray round things around a target
    /// field printed the other way ([`drop_stray_polarity`]), default
    /// [`STRAY_POLARITY_SHARE`]; 0 keeps both polarities whatever their shares.
    pub stray_polarity_share: f64,
}

/// The default [`DetectConfig::stray_polarity_share`]: a field printed in both polarities
/// (the paper's lab, black and white targets) shows each in quantity, while the white pins,
/// pebbles and highlights beside BoofCV's black dot grids are 0.25–0.5 % of the detections.
pub const STRAY_POLARITY_SHARE: f64 = 0.05;

/// The default [`DetectConfig::max_level_ratio`]. BoofCV's printed black dots show a ratio of
/// at most 0.24 in its stills and 0.36 in its hand-held H.264 video (blurred dots of 2.5 px
/// among them); the simulated lab's printed targets at most 0.30; the false detections on
/// the speckled simulated lab's paint blotches (albedo shifts of up to 0.35 on a 0.55 wall)
/// 0.04–0.80, half of them above 0.42 (`tests/detect.rs`). Without an interior the fitted
/// levels are no measure: white discs of b ≈ 3 px blurred by σ 2 px on the simulated lab's
/// narrow black plates fit at 0.50–0.53.
pub const MAX_LEVEL_RATIO: f64 = 0.5;

/// Fewest detections in a set before a polarity is judged stray: a handful of targets says
/// nothing about how the field is printed.
const MIN_DETECTIONS_TO_JUDGE_POLARITY: usize = 20;

impl Default for DetectConfig {
    fn default() -> Self {
        DetectConfig {
            min_semi_minor_px: MIN_SEMI_MINOR_PX,
            max_semi_major_fraction: 0.25,
            min_axis_ratio: 0.15,
            border_margin_px: 2.0,
            min_support: 0.9,
            max_rms_px: 0.25,
            max_shape_deviation: 0.08,
            min_contrast: 50.0,
            min_resolution: 2.0,
            max_interior_spread: 0.15,
            max_ring_spread: 0.15,
            max_step_residual: 0.1,
            max_level_ratio: MAX_LEVEL_RATIO,
            polarity: None,
            threshold_sigma: 6.0,
            stray_polarity_share: STRAY_POLARITY_SHARE,
        }
    }
}

/// A bad detection option.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("detection option `{field}`: {reason}")]
pub struct DetectConfigError {
    /// The option.
    pub field: &'static str,
    /// What is wrong.
    pub reason: String,
}

impl DetectConfig {
    /// Checks the values.
    ///
    /// # Errors
    ///
    /// [`DetectConfigError`] naming the first bad option.
    pub fn validate(&self) -> Result<(), DetectConfigError> {
        let bad = |field, reason: &str| {
            Err(DetectConfigError {
                field,
                reason: reason.into(),
            })
        };
        if !(self.min_semi_minor_px >= 1.0 && self.min_semi_minor_px.is_finite()) {
            return bad("min_semi_minor_px", "must be at least 1 px");
        }
        if !(self.max_semi_major_fraction > 0.0 && self.max_semi_major_fraction <= 1.0) {
            return bad("max_semi_major_fraction", "must be in (0, 1]");
        }
        if !(0.0..=1.0).contains(&self.min_axis_ratio) {
            return bad("min_axis_ratio", "must be in [0, 1]");
        }
        if !(0.0..=1.0).contains(&self.min_support) {
            return bad("min_support", "must be in [0, 1]");
        }
        if !(0.0..=1.0).contains(&self.max_level_ratio) {
            return bad("max_level_ratio", "must be in [0, 1]");
        }
        if !(0.0..0.5).contains(&self.stray_polarity_share) {
            return bad("stray_polarity_share", "must be in [0, 0.5)");
        }
        for (field, v) in [
            ("border_margin_px", self.border_margin_px),
            ("max_rms_px", self.max_rms_px),
            ("max_shape_deviation", self.max_shape_deviation),
            ("min_resolution", self.min_resolution),
            ("min_contrast", self.min_contrast),
            ("max_interior_spread", self.max_interior_spread),
            ("max_ring_spread", self.max_ring_spread),
            ("max_step_residual", self.max_step_residual),
            ("threshold_sigma", self.threshold_sigma),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(field, "must be a finite value ≥ 0");
            }
        }
        Ok(())
    }
}

/// Which way round a target is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DiscPolarity {
    /// A dark disc on a light background.
    Dark,
    /// A light disc on a dark background.
    Light,
}

/// One detected target.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DetectedEllipse {
    /// Centre u (px).
    pub cx: f64,
    /// Centre v (px).
    pub cy: f64,
    /// Semi-major axis (px).
    pub a: f64,
    /// Semi-minor axis (px).
    pub b: f64,
    /// Angle of the major axis from +u toward +v (rad).
    pub theta: f64,
    /// The point conic, unit Frobenius norm, interior negative.
    pub conic: [[f64; 3]; 3],
    /// RMS of the orthogonal residuals of the edge points (px).
    pub rms_px: f64,
    /// Standard deviation of the centre from the fit (px).
    pub centre_std_px: f64,
    /// Dark or light disc.
    pub polarity: DiscPolarity,
    /// Grey-level difference between outside and inside (positive).
    pub contrast: f64,
    /// Grey level inside the disc, from the fitted blurred step.
    pub inside_level: f64,
    /// Grey level outside the disc, from the fitted blurred step.
    pub outside_level: f64,
    /// Fraction of the normals that showed the edge.
    pub support: f64,
    /// Edge points used in the fit.
    pub edge_points: usize,
    /// Edge width: σ of the Gaussian blur across the edge, from the fitted blurred step (px).
    pub edge_width_px: f64,
    /// RMS of the median edge profile about the blurred step, relative to the contrast.
    pub step_residual: f64,
    /// RMS of the interior about a plane, relative to the contrast (`None`: no interior deeper
    /// than two edge widths).
    pub interior_spread: Option<f64>,
    /// Spread of the surround's level just outside, relative to the contrast.
    pub ring_spread: f64,
    /// Amplitude of the edge residuals' harmonics 3–6 (px), which no ellipse has.
    pub shape_px: f64,
}

impl DetectedEllipse {
    /// The ellipse.
    #[must_use]
    pub fn ellipse(&self) -> Ellipse {
        Ellipse {
            cx: self.cx,
            cy: self.cy,
            a: self.a,
            b: self.b,
            theta: self.theta,
        }
    }
}

/// Counts of what happened, for diagnostics.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DetectDiagnostics {
    /// Estimated image noise σ (grey levels).
    pub noise_sigma: f64,
    /// Canny thresholds used (L1 Sobel magnitude).
    pub thresholds: (u16, u16),
    /// Edge chains.
    pub chains: usize,
    /// Candidate ellipses from arcs.
    pub candidates: usize,
    /// Rejected for too little edge support all round.
    pub rejected_support: usize,
    /// Rejected for polarity, contrast, resolution, or grey levels that are no disc: no
    /// blurred step across the edge, a non-uniform interior or surround.
    pub rejected_appearance: usize,
    /// Rejected for a large fit residual or a shape no ellipse has.
    pub rejected_fit: usize,
    /// Rejected for size, shape or the frame border.
    pub rejected_geometry: usize,
    /// Removed as duplicates or overlaps.
    pub duplicates: usize,
    /// Dropped as the stray polarity of the set of frames detected together
    /// ([`drop_stray_polarity`]).
    #[serde(default)]
    pub stray_polarity: usize,
}

/// The ellipses found in one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// Frame width (px).
    pub width: usize,
    /// Frame height (px).
    pub height: usize,
    /// The targets, sorted by centre (v, then u).
    pub ellipses: Vec<DetectedEllipse>,
    /// What happened on the way.
    pub diagnostics: DetectDiagnostics,
}

/// Half extents of an ellipse's bounding box.
fn half_extents(e: &Ellipse) -> (f64, f64) {
    let (s, c) = e.theta.sin_cos();
    (
        (e.a * e.a * c * c + e.b * e.b * s * s).sqrt(),
        (e.a * e.a * s * s + e.b * e.b * c * c).sqrt(),
    )
}

/// Whether point `p` lies inside ellipse `e`.
fn inside(e: &Ellipse, p: &nalgebra::Vector2<f64>) -> bool {
    let (s, c) = e.theta.sin_cos();
    let d = p - e.centre();
    let (u, v) = (c * d.x + s * d.y, -s * d.x + c * d.y);
    (u / e.a).powi(2) + (v / e.b).powi(2) <= 1.0
}

/// A detector with reusable buffers: detecting many frames of one size reuses its memory
/// (a 4K frame needs about 60 MB of gradients and flags).
#[derive(Debug)]
pub struct Detector {
    config: DetectConfig,
    gray: GrayImage,
    gradients: edges::Gradients,
    flags: Vec<u8>,
    /// The half-resolution pass's buffers.
    half: GrayImage,
    half_gradients: edges::Gradients,
    half_flags: Vec<u8>,
}

impl Detector {
    /// A detector with `config`.
    ///
    /// # Errors
    ///
    /// [`DetectConfigError`] for a bad configuration.
    pub fn new(config: DetectConfig) -> Result<Self, DetectConfigError> {
        config.validate()?;
        Ok(Detector {
            config,
            gray: GrayImage {
                width: 0,
                height: 0,
                data: Vec::new(),
            },
            gradients: edges::Gradients::empty(),
            flags: Vec::new(),
            half: GrayImage {
                width: 0,
                height: 0,
                data: Vec::new(),
            },
            half_gradients: edges::Gradients::empty(),
            half_flags: Vec::new(),
        })
    }

    /// Finds the targets of any frame (converted to grey). Any image, including an empty,
    /// tiny, blank or saturated one, gives a (possibly empty) result.
    pub fn detect(&mut self, frame: &::image::DynamicImage) -> Detection {
        let mut gray = std::mem::replace(
            &mut self.gray,
            GrayImage {
                width: 0,
                height: 0,
                data: Vec::new(),
            },
        );
        gray.set_from(frame);
        let d = self.detect_gray(&gray);
        self.gray = gray;
        d
    }

    /// Finds the targets of a grey frame.
    pub fn detect_gray(&mut self, img: &GrayImage) -> Detection {
        let config = &self.config;
        let (w, h) = (img.width, img.height);
        let mut result = Detection {
            width: w,
            height: h,
            ..Default::default()
        };
        if w < 16 || h < 16 {
            return result;
        }
        let sigma = edges::noise_sigma(img);
        let sobel_sigma = 3.46 * sigma;
        let low = (config.threshold_sigma * sobel_sigma)
            .round()
            .clamp(24.0, 30000.0) as u16;
        let high = low.saturating_mul(2);
        edges::sobel_into(img, &mut self.gradients);
        let g = &self.gradients;
        let strong = edges::suppress_into(g, low, high, &mut self.flags);
        let chains = edges::link(g, &mut self.flags, &strong, 8);
        let limits = contours::CandidateLimits {
            min_semi_minor: config.min_semi_minor_px,
            max_semi_major: config.max_semi_major_fraction * w.min(h) as f64,
            min_axis_ratio: config.min_axis_ratio,
        };
        let mut cands = contours::candidates(g, &chains, &limits);
        let mut chain_count = chains.len();
        // A blurred edge (several px wide) breaks into short, ragged chains at full resolution;
        // at half resolution it is half as wide and its chains hold together. Candidates found
        // there (full-resolution semi-minor axis ≥ 5 px) and not already proposed are refined at
        // full resolution like the others.
        img.half_into(&mut self.half);
        let half = &self.half;
        if half.width >= 16 && half.height >= 16 {
            let half_sigma = edges::noise_sigma(half);
            let half_low = (config.threshold_sigma * 3.46 * half_sigma)
                .round()
                .clamp(24.0, 30000.0) as u16;
            edges::sobel_into(half, &mut self.half_gradients);
            let hg = &self.half_gradients;
            let strong = edges::suppress_into(
                hg,
                half_low,
                half_low.saturating_mul(2),
                &mut self.half_flags,
            );
            let half_chains = edges::link(hg, &mut self.half_flags, &strong, 8);
            chain_count += half_chains.len();
            let half_limits = contours::CandidateLimits {
                min_semi_minor: (0.5 * config.min_semi_minor_px).max(2.5),
                max_semi_major: 0.5 * limits.max_semi_major,
                min_axis_ratio: config.min_axis_ratio,
            };
            for mut c in contours::candidates(hg, &half_chains, &half_limits) {
                let e = &mut c.ellipse;
                (e.cx, e.cy, e.a, e.b) = (2.0 * e.cx, 2.0 * e.cy, 2.0 * e.a, 2.0 * e.b);
                if !cands
                    .iter()
                    .any(|k| k.polarity == c.polarity && contours::same(&k.ellipse, &c.ellipse))
                {
                    cands.push(c);
                }
            }
        }
        let d = &mut result.diagnostics;
        (d.noise_sigma, d.thresholds, d.chains, d.candidates) =
            (sigma, (low, high), chain_count, cands.len());
        // Slope of a real edge along its normal is far above the noise of the profile
        // derivative (about 2.5 σ): require 5 σ and at least 4 grey levels per px.
        let min_slope = (5.0 * sigma).max(4.0);
        let mut accepted: Vec<(f64, DetectedEllipse)> = Vec::new();
        for cand in &cands {
            if let Some(det) = validate(img, cand, config, &limits, sigma, min_slope, d) {
                accepted.push(det);
            }
        }
        // Non-overlapping ellipses: where one centre lies inside another, keep the better one.
        accepted.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut kept: Vec<DetectedEllipse> = Vec::new();
        for (_, det) in accepted {
            let e = det.ellipse();
            if kept
                .iter()
                .any(|k| inside(&k.ellipse(), &e.centre()) || inside(&e, &k.ellipse().centre()))
            {
                d.duplicates += 1;
                continue;
            }
            kept.push(det);
        }
        kept.sort_by(|a, b| a.cy.total_cmp(&b.cy).then(a.cx.total_cmp(&b.cx)));
        result.ellipses = kept;
        result
    }
}

/// Refines and validates one candidate; the score ranks overlapping detections.
fn validate(
    img: &GrayImage,
    cand: &contours::Candidate,
    config: &DetectConfig,
    limits: &contours::CandidateLimits,
    sigma: f64,
    min_slope: f64,
    d: &mut DetectDiagnostics,
) -> Option<(f64, DetectedEllipse)> {
    let (w, h) = (img.width, img.height);
    let polarity = if cand.polarity > 0.0 {
        DiscPolarity::Dark
    } else {
        DiscPolarity::Light
    };
    // The candidate's polarity is known before any refinement.
    if config.polarity.is_some_and(|p| p != polarity) {
        d.rejected_appearance += 1;
        return None;
    }
    let Some(mut r) = refine::refine(img, &cand.ellipse, cand.polarity, min_slope) else {
        d.rejected_support += 1;
        return None;
    };
    let e = r.fit.ellipse;
    let (hx, hy) = half_extents(&e);
    let margin = config.border_margin_px + 1.0;
    let geometry_ok = e.b >= config.min_semi_minor_px
        && e.a <= limits.max_semi_major
        && e.b >= config.min_axis_ratio * e.a
        && e.cx - hx >= margin
        && e.cy - hy >= margin
        && e.cx + hx <= w as f64 - margin
        && e.cy + hy <= h as f64 - margin;
    if !geometry_ok {
        d.rejected_geometry += 1;
        return None;
    }
    let support = r.profiles.points.len() as f64 / r.profiles.sampled as f64;
    if support < config.min_support {
        d.rejected_support += 1;
        return None;
    }
    let width0 = refine::edge_width(&r.profiles);
    let max_rms = config.max_rms_px.max(RMS_PER_EDGE_WIDTH * width0);
    if r.fit.rms_px > max_rms || r.shape_px > config.max_shape_deviation * e.b {
        d.rejected_fit += 1;
        return None;
    }
    let (inner, outer, _) = refine::levels(&r.profiles);
    let Some(look) = step::appearance(img, &e, outer - inner, width0, sigma) else {
        d.rejected_appearance += 1;
        return None;
    };
    let contrast = look.step.contrast();
    let (dark, light) = (
        look.step.inside.min(look.step.outside),
        look.step.inside.max(look.step.outside),
    );
    // Spreads are RMS about a fit; the image noise adds about its σ to each.
    let noise_share = 2.0 * sigma / contrast.abs().max(1e-9);
    if cand.polarity * contrast < config.min_contrast
        || e.b < config.min_resolution * look.step.width_px
        || look.step.residual > config.max_step_residual
        || (look.interior_spread.is_some() && dark > config.max_level_ratio * light)
        || look.ring_spread > config.max_ring_spread + noise_share
        || look
            .interior_spread
            .is_some_and(|s| s > config.max_interior_spread + noise_share)
    {
        d.rejected_appearance += 1;
        return None;
    }
    refine::correlate_centre_std(&mut r);
    let conic = e.to_conic();
    let det = DetectedEllipse {
        cx: e.cx,
        cy: e.cy,
        a: e.a,
        b: e.b,
        theta: e.theta,
        conic: [
            [conic[(0, 0)], conic[(0, 1)], conic[(0, 2)]],
            [conic[(1, 0)], conic[(1, 1)], conic[(1, 2)]],
            [conic[(2, 0)], conic[(2, 1)], conic[(2, 2)]],
        ],
        rms_px: r.fit.rms_px,
        centre_std_px: r.fit.centre_std_px,
        polarity,
        contrast: contrast.abs(),
        inside_level: look.step.inside,
        outside_level: look.step.outside,
        support,
        edge_points: r.fit.inliers,
        edge_width_px: look.step.width_px,
        step_residual: look.step.residual,
        interior_spread: look.interior_spread,
        ring_spread: look.ring_spread,
        shape_px: r.shape_px,
    };
    Some((
        support * contrast.abs() * (r.fit.inliers as f64).sqrt(),
        det,
    ))
}

/// Drops, across the detections of a set of frames, the discs of a stray polarity: when one
/// polarity makes up at most `share` of the set's detections (and the set holds at least
/// 20), its discs are the round things around a target field
/// printed the other way — white pins on a board of black dots, light pebbles beside it —
/// which pass every appearance test a dot of the field passes (shaded domes in JPEG look as
/// flat as dots in H.264). OpenCV's blob detector looks for dark blobs only unless told
/// otherwise; this keeps both polarities when the field has both. Each frame's
/// [`DetectDiagnostics::stray_polarity`] counts what it lost. Returns the polarity dropped, if
/// any.
pub fn drop_stray_polarity(detections: &mut [Detection], share: f64) -> Option<DiscPolarity> {
    let all = || detections.iter().flat_map(|d| &d.ellipses);
    let light = all().filter(|e| e.polarity == DiscPolarity::Light).count();
    let total = all().count();
    if total < MIN_DETECTIONS_TO_JUDGE_POLARITY || share <= 0.0 {
        return None;
    }
    let stray = if light > 0 && light as f64 <= share * total as f64 {
        DiscPolarity::Light
    } else if light < total && (total - light) as f64 <= share * total as f64 {
        DiscPolarity::Dark
    } else {
        return None;
    };
    for d in detections.iter_mut() {
        let before = d.ellipses.len();
        d.ellipses.retain(|e| e.polarity != stray);
        d.diagnostics.stray_polarity += before - d.ellipses.len();
    }
    Some(stray)
}

/// Finds the circular targets of one grey frame (a one-off [`Detector`]).
///
/// # Errors
///
/// [`DetectConfigError`] for a bad configuration. Any image, including an empty, tiny, blank or
/// saturated one, gives a (possibly empty) result.
pub fn detect_ellipses(
    img: &GrayImage,
    config: &DetectConfig,
) -> Result<Detection, DetectConfigError> {
    Ok(Detector::new(config.clone())?.detect_gray(img))
}

/// Detects the targets of any frame (converted to grey), with a one-off [`Detector`].
///
/// # Errors
///
/// As [`detect_ellipses`].
pub fn detect_in_frame(
    frame: &::image::DynamicImage,
    config: &DetectConfig,
) -> Result<Detection, DetectConfigError> {
    Ok(Detector::new(config.clone())?.detect(frame))
}

/// Why the targets of a set of frame files could not be detected.
#[derive(Debug, thiserror::Error)]
pub enum DetectFilesError {
    /// A bad configuration.
    #[error(transparent)]
    Config(#[from] DetectConfigError),
    /// A frame could not be read.
    #[error(transparent)]
    Read(#[from] crate::io::ReadError),
}

/// Detects the targets of frame files in parallel (one frame in memory per worker, one
/// [`Detector`] per worker): per file, the detected ellipses in observed pixels, in the order
/// of `paths`, without the set's stray polarity ([`drop_stray_polarity`]). Every frame must be `size` = (width, height) (the SfM model's camera): each
/// file's header is checked before any frame is decoded, and the decoder may allocate only what
/// a frame of that size needs ([`crate::io::frames::read_frame_sized`]). `progress` is called
/// once per frame done.
///
/// # Errors
///
/// [`DetectFilesError`]: a bad configuration, or the first frame (in `paths` order) that cannot
/// be read or is of another size.
pub fn detect_frame_files(
    paths: &[std::path::PathBuf],
    size: (u32, u32),
    config: &DetectConfig,
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<Vec<Ellipse>>, DetectFilesError> {
    use rayon::prelude::*;
    Detector::new(config.clone())?;
    // Every header first: a frame of another size fails before minutes of detection.
    if let Some((path, found)) = crate::io::frames::first_of_another_size(paths, size)? {
        return Err(crate::io::ReadError::new(
            path,
            crate::io::ReadErrorKind::Invalid(format!(
                "the frame is {}x{} but the model's camera is {}x{}: the frames and the model do not belong together",
                found.0, found.1, size.0, size.1
            )),
        )
        .into());
    }
    let mut detections = paths
        .par_iter()
        .map_init(
            || Detector::new(config.clone()),
            |detector, path| {
                let detector = detector.as_mut().map_err(|e| e.clone())?;
                let image = crate::io::frames::read_frame_sized(path, Some(size))?;
                let detection = detector.detect(&image);
                progress();
                Ok(detection)
            },
        )
        .collect::<Result<Vec<Detection>, DetectFilesError>>()?;
    drop_stray_polarity(&mut detections, config.stray_polarity_share);
    Ok(detections
        .iter()
        .map(|d| d.ellipses.iter().map(DetectedEllipse::ellipse).collect())
        .collect())
}
