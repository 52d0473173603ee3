//! Robust estimation (layer 1): one least-median-of-squares driver (Rousseeuw & Leroy 1987)
//! behind a small estimator trait, random and bucketed samplers (Zhang et al. 1995), the robust
//! scale, and the estimators built on it: the fundamental matrix and multi-view triangulation.
//! docs/math.md §4.

pub mod fundamental;
pub mod triangulation;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A standard normal deviate (Box–Muller, 1958): `√(−2 ln u₁) cos(2π u₂)` with `u₁` in
/// `(0, 1)` (never 0, so the logarithm is finite) and `u₂` in `[0, 1)`. The one normal sampler
/// of the crate: the simulator's noise, the site's pose Monte Carlo and the tests draw from it,
/// so a seed gives the same deviates everywhere.
pub fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Two independent standard normal deviates from one draw of [`standard_normal`]'s pair
/// `(u₁, u₂)`: the cosine and the sine of the same angle.
pub fn standard_normal_pair<R: Rng + ?Sized>(rng: &mut R) -> (f64, f64) {
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random();
    let r = (-2.0 * u1.ln()).sqrt();
    let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
    (r * c, r * s)
}

/// √χ²₀.₉₇₅ with 2 degrees of freedom (paper eq. 2): 2.7162.
pub const SQRT_CHI2_975_2DOF: f64 = 2.716_203_1;
/// √χ²₀.₉₉₉ with 2 degrees of freedom: 3.7169 (`χ² = −2 ln 0.001`).
pub const SQRT_CHI2_999_2DOF: f64 = 3.716_922_2;
/// χ²₀.₉₇₅ with 2 degrees of freedom: 7.3778.
pub const CHI2_975_2DOF: f64 = 7.377_758_9;
/// Median of χ²(2): 2·ln 2 = 1.3863.
pub const CHI2_MEDIAN_2DOF: f64 = std::f64::consts::LN_2 * 2.0;
/// Median of χ²(1): 0.4549.
pub const CHI2_MEDIAN_1DOF: f64 = 0.454_936_4;
/// 1/Φ⁻¹(0.75): makes the median absolute residual a consistent σ for Gaussian noise.
pub const MAD_TO_SIGMA: f64 = 1.482_6;

/// A model estimated from minimal samples.
pub trait Estimator {
    /// The model type.
    type Model: Clone;
    /// Points in a minimal sample.
    const SAMPLE_SIZE: usize;
    /// Number of data points.
    fn len(&self) -> usize;
    /// Whether there are no data points.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Models fitting the sample (none for a degenerate sample; the 7-point method gives up to
    /// three).
    fn fit(&self, sample: &[usize]) -> Vec<Self::Model>;
    /// Squared residual of point `i` under `model`.
    fn residual_squared(&self, model: &Self::Model, i: usize) -> f64;
}

/// Draws minimal samples.
pub trait Sampler {
    /// `k` distinct point indices, or `None` if no valid sample can be drawn.
    fn sample(&mut self, k: usize, rng: &mut ChaCha8Rng) -> Option<Vec<usize>>;
}

/// Uniform samples of distinct indices.
#[derive(Clone, Debug)]
pub struct UniformSampler {
    /// Number of points.
    pub n: usize,
}

impl Sampler for UniformSampler {
    fn sample(&mut self, k: usize, rng: &mut ChaCha8Rng) -> Option<Vec<usize>> {
        if k > self.n {
            return None;
        }
        let mut s = Vec::with_capacity(k);
        while s.len() < k {
            let i = rng.random_range(0..self.n);
            if !s.contains(&i) {
                s.push(i);
            }
        }
        Some(s)
    }
}

/// Zhang's bucketing: the bounding box of the points (in the first image) is split into a
/// `b × b` grid; a sample takes `k` different non-empty buckets, each with probability
/// proportional to its point count, and one point uniformly from each. This spreads samples
/// over the image and avoids near-degenerate clustered ones.
#[derive(Clone, Debug)]
pub struct BucketSampler {
    buckets: Vec<Vec<usize>>,
    cumulative: Vec<usize>,
}

impl BucketSampler {
    /// Buckets `points` on a `grid × grid` grid over their bounding box.
    #[must_use]
    pub fn new(points: &[nalgebra::Vector2<f64>], grid: usize) -> Self {
        let grid = grid.max(1);
        let (mut lo, mut hi) = (
            nalgebra::Vector2::repeat(f64::INFINITY),
            nalgebra::Vector2::repeat(f64::NEG_INFINITY),
        );
        for p in points {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let size = (hi - lo).map(|v| v.max(1e-9));
        let mut cells = vec![Vec::new(); grid * grid];
        for (i, p) in points.iter().enumerate() {
            let cx = (((p.x - lo.x) / size.x * grid as f64) as usize).min(grid - 1);
            let cy = (((p.y - lo.y) / size.y * grid as f64) as usize).min(grid - 1);
            cells[cy * grid + cx].push(i);
        }
        let buckets: Vec<Vec<usize>> = cells.into_iter().filter(|c| !c.is_empty()).collect();
        let mut cumulative = Vec::with_capacity(buckets.len());
        let mut total = 0;
        for b in &buckets {
            total += b.len();
            cumulative.push(total);
        }
        BucketSampler {
            buckets,
            cumulative,
        }
    }
}

impl Sampler for BucketSampler {
    fn sample(&mut self, k: usize, rng: &mut ChaCha8Rng) -> Option<Vec<usize>> {
        if k > self.buckets.len() {
            return None;
        }
        let total = *self.cumulative.last()?;
        let mut chosen: Vec<usize> = Vec::with_capacity(k);
        let mut guard = 0;
        while chosen.len() < k {
            guard += 1;
            if guard > 1000 * k {
                return None;
            }
            let r = rng.random_range(0..total);
            let b = self.cumulative.partition_point(|&c| c <= r);
            if !chosen.contains(&b) {
                chosen.push(b);
            }
        }
        Some(
            chosen
                .iter()
                .map(|&b| self.buckets[b][rng.random_range(0..self.buckets[b].len())])
                .collect(),
        )
    }
}

/// Options of the LMedS driver.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LmedsConfig {
    /// Probability that at least one sample is outlier-free, default 0.99.
    pub confidence: f64,
    /// Outlier fraction the sample count is computed for, default 0.5 (LMedS's breakdown
    /// point).
    pub outlier_fraction: f64,
    /// Cap on the number of samples, default 2000.
    pub max_samples: usize,
    /// Inlier cut-off in robust σ, default 2.5 (Zhang 1998).
    pub inlier_sigmas: f64,
}

impl Default for LmedsConfig {
    fn default() -> Self {
        LmedsConfig {
            confidence: 0.99,
            outlier_fraction: 0.5,
            max_samples: 2000,
            inlier_sigmas: 2.5,
        }
    }
}

/// Samples needed to draw an outlier-free sample of size `p` with probability `confidence`
/// when a fraction `eps` of the data are outliers: `⌈log(1 − P) / log(1 − (1 − ε)^p)⌉`.
#[must_use]
pub fn samples_needed(confidence: f64, eps: f64, p: usize) -> usize {
    let good = (1.0 - eps).clamp(1e-12, 1.0).powi(p as i32);
    if good >= 1.0 {
        return 1;
    }
    ((1.0 - confidence).ln() / (1.0 - good).ln())
        .ceil()
        .max(1.0) as usize
}

/// The robust σ from the median squared residual (math §4.1 step 8):
/// `1.4826·(1 + 5/(n − p))·sqrt(median)`.
#[must_use]
pub fn robust_sigma(median_sq: f64, n: usize, p: usize) -> f64 {
    let small = if n > p { 5.0 / (n - p) as f64 } else { 5.0 };
    MAD_TO_SIGMA * (1.0 + small) * median_sq.max(0.0).sqrt()
}

/// The (⌊n/2⌋+1)-th smallest value: the median of an odd count, the upper of the two middle
/// values of an even one; `+∞` when there are none. Reorders `values`.
#[must_use]
pub fn upper_median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::INFINITY;
    }
    let k = values.len() / 2;
    *values.select_nth_unstable_by(k, f64::total_cmp).1
}

/// The ⌈n/2⌉-th smallest value (the median rule of Rousseeuw & Leroy).
#[must_use]
pub fn lower_median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::INFINITY;
    }
    let k = values.len().div_ceil(2) - 1;
    *values.select_nth_unstable_by(k, f64::total_cmp).1
}

/// The outcome of LMedS.
#[derive(Clone, Debug)]
pub struct LmedsResult<M> {
    /// The model with the least median of squared residuals.
    pub model: M,
    /// That median.
    pub median_sq: f64,
    /// Robust σ of the residuals.
    pub sigma: f64,
    /// Points within `inlier_sigmas·σ`.
    pub inliers: Vec<bool>,
    /// Samples drawn.
    pub samples: usize,
}

/// Least median of squares: draws the number of samples that gives an outlier-free one with the
/// configured confidence at the configured outlier fraction (capped), and keeps the model with
/// the least median squared residual. (The count is not adapted to the best model so far: its
/// robust σ is only meaningful once the model is right, and a wrong first model would stop the
/// search.) `None` with too few points or no valid sample.
pub fn lmeds<E: Estimator>(
    est: &E,
    sampler: &mut dyn Sampler,
    config: &LmedsConfig,
    seed: u64,
) -> Option<LmedsResult<E::Model>> {
    let n = est.len();
    if n < E::SAMPLE_SIZE {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let needed = samples_needed(config.confidence, config.outlier_fraction, E::SAMPLE_SIZE)
        .min(config.max_samples);
    let mut best: Option<(E::Model, f64)> = None;
    let mut residuals = vec![0.0; n];
    let mut drawn = 0;
    let mut failures = 0;
    while drawn < needed {
        let Some(sample) = sampler.sample(E::SAMPLE_SIZE, &mut rng) else {
            failures += 1;
            if failures > 100 {
                break;
            }
            continue;
        };
        drawn += 1;
        for model in est.fit(&sample) {
            for (i, r) in residuals.iter_mut().enumerate() {
                *r = est.residual_squared(&model, i);
            }
            let med = lower_median(&mut residuals);
            if med.is_finite() && best.as_ref().is_none_or(|(_, b)| med < *b) {
                best = Some((model, med));
            }
        }
    }
    let (model, median_sq) = best?;
    let sigma = robust_sigma(median_sq, n, E::SAMPLE_SIZE);
    let cut = (config.inlier_sigmas * sigma).powi(2);
    let inliers = (0..n)
        .map(|i| est.residual_squared(&model, i) <= cut)
        .collect();
    Some(LmedsResult {
        model,
        median_sq,
        sigma,
        inliers,
        samples: drawn,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A line through 2 points, residual = vertical distance.
    struct Line(Vec<(f64, f64)>);
    impl Estimator for Line {
        type Model = (f64, f64);
        const SAMPLE_SIZE: usize = 2;
        fn len(&self) -> usize {
            self.0.len()
        }
        fn fit(&self, s: &[usize]) -> Vec<(f64, f64)> {
            let ((x0, y0), (x1, y1)) = (self.0[s[0]], self.0[s[1]]);
            if (x1 - x0).abs() < 1e-12 {
                return vec![];
            }
            let m = (y1 - y0) / (x1 - x0);
            vec![(m, y0 - m * x0)]
        }
        fn residual_squared(&self, (m, c): &(f64, f64), i: usize) -> f64 {
            let (x, y) = self.0[i];
            (y - m * x - c).powi(2)
        }
    }

    #[test]
    fn the_medians_pick_the_middle_order_statistics() {
        // Odd: both the middle value; even: the lower and the upper of the two middle ones.
        assert_eq!(upper_median(&mut [5.0, 1.0, 3.0]), 3.0);
        assert_eq!(lower_median(&mut [5.0, 1.0, 3.0]), 3.0);
        assert_eq!(upper_median(&mut [4.0, 1.0, 3.0, 2.0]), 3.0);
        assert_eq!(lower_median(&mut [4.0, 1.0, 3.0, 2.0]), 2.0);
        assert_eq!(upper_median(&mut []), f64::INFINITY);
    }

    #[test]
    fn sample_counts_match_the_table_of_math_4_1() {
        assert_eq!(samples_needed(0.99, 0.3, 7), 54);
        assert_eq!(samples_needed(0.99, 0.4, 7), 163);
        assert_eq!(samples_needed(0.99, 0.5, 7), 588);
        assert_eq!(samples_needed(0.99, 0.3, 8), 78);
        assert_eq!(samples_needed(0.99, 0.5, 8), 1177);
    }

    #[test]
    fn lmeds_ignores_forty_percent_outliers() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let pts: Vec<(f64, f64)> = (0..200)
            .map(|k| {
                let x = f64::from(k);
                if k % 5 < 2 {
                    (x, rng.random_range(-100.0..100.0))
                } else {
                    (x, 2.0 * x + 1.0 + rng.random_range(-0.01..0.01))
                }
            })
            .collect();
        let est = Line(pts);
        let r = lmeds(
            &est,
            &mut UniformSampler { n: 200 },
            &LmedsConfig::default(),
            7,
        )
        .unwrap();
        assert!(
            (r.model.0 - 2.0).abs() < 1e-3 && (r.model.1 - 1.0).abs() < 0.1,
            "{:?}",
            r.model
        );
        let inliers = r.inliers.iter().filter(|b| **b).count();
        assert!((118..=122).contains(&inliers), "{inliers} inliers");
        // Uniform noise of ±0.01 has σ = 0.0058; the robust σ is of that order.
        assert!(r.sigma < 0.02, "σ {}", r.sigma);
    }

    #[test]
    fn bucket_sampler_draws_distinct_buckets() {
        let pts: Vec<_> = (0..100)
            .map(|k| nalgebra::Vector2::new(f64::from(k % 10), f64::from(k / 10)))
            .collect();
        let mut s = BucketSampler::new(&pts, 4);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..100 {
            let sample = s.sample(7, &mut rng).unwrap();
            let cells: std::collections::BTreeSet<_> = sample
                .iter()
                .map(|&i| {
                    let p = pts[i];
                    (
                        ((p.x / 9.0) * 4.0).min(3.999) as usize,
                        ((p.y / 9.0) * 4.0).min(3.999) as usize,
                    )
                })
                .collect();
            assert_eq!(cells.len(), 7);
        }
        assert!(s.sample(17, &mut rng).is_none());
    }
}
