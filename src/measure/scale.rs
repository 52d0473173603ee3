//! The cloud's scale from targets surveyed by the TLS (paper, "Evaluation of Impact of
//! Calibration on Pipe Reconstruction", steps 1–7): the reconstructed target centres (Algorithm 3
//! corrected, triangulated in the SfM frame) are associated with the TLS target list, and
//!
//! * the paper's scale is the TLS distance over the reconstructed distance of the two
//!   associated targets seen in the most views (step 7);
//! * beside it, a least-squares similarity over every associated target gives a scale with a
//!   standard deviation from its own residuals (three or more targets).
//!
//! Association is automatic with three or more TLS targets: every well-shaped triangle of the
//! best-observed reconstructed targets is compared with every ordered TLS triple (equal ratios of
//! the three side lengths: a similar triangle), the similarity of each consistent triple is
//! scored by how many reconstructed targets it brings within tolerance of a TLS target, and the
//! best consensus wins (most targets, then smallest residuals). Proper rotations only: a mirrored
//! match is refused. Where four or more targets exist on both sides, the consensus must hold four
//! (three only show two similar triangles; a fourth verifies them). With exactly two TLS targets nothing can be checked: the two reconstructed
//! targets with the most views are taken to be them, as the paper does (the distance is
//! symmetric, so their order does not matter).

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::adjust::{Similarity, similarity_from_points};

/// A target centre reconstructed in the SfM frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReconstructedTarget {
    /// Centre (SfM frame units).
    pub point: Point3<f64>,
    /// Number of views it was triangulated from.
    pub views: usize,
}

/// Options of [`estimate_scale`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleConfig {
    /// Relative tolerance of distance ratios (similar triangles) and of a target's distance to
    /// its TLS partner after the similarity, as a fraction of the TLS targets' median spacing.
    /// Default 0.01.
    pub tolerance: f64,
    /// The TLS targets' coordinate standard deviation (m) per axis, used for the scale's
    /// standard deviation when only two targets are given (no redundancy). Default 1 mm.
    pub target_sigma_m: f64,
    /// Reconstructed targets (most views first) whose triangles seed the association, 3 to
    /// [`MAX_SEEDS`]. Default 10.
    pub seeds: usize,
}

impl Default for ScaleConfig {
    fn default() -> Self {
        ScaleConfig {
            tolerance: 0.01,
            target_sigma_m: 0.001,
            seeds: 10,
        }
    }
}

/// Why no scale.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScaleError {
    /// Fewer than two TLS targets or reconstructed targets.
    #[error("the scale needs at least two {what}; found {found}")]
    TooFew {
        /// What is missing.
        what: &'static str,
        /// How many there are.
        found: usize,
    },
    /// No consistent association.
    #[error(
        "no {required} reconstructed targets match the TLS targets' geometry (best consensus: {found}); check that the TLS list belongs to this site"
    )]
    NoAssociation {
        /// Targets in the best consensus.
        found: usize,
        /// Targets needed.
        required: usize,
    },
    /// The two targets coincide.
    #[error("the two targets used for the scale are {0:.3e} apart: degenerate")]
    Degenerate(f64),
    /// More TLS targets than the association handles.
    #[error(
        "{found} TLS targets: the automatic association handles at most {max} (its time grows faster than the square of the list); select this site's targets or give a shorter list"
    )]
    TooManyTls {
        /// TLS targets given.
        found: usize,
        /// [`MAX_TLS_TARGETS`].
        max: usize,
    },
}

/// The longest TLS list the automatic association takes: its time grows with the square of the
/// list and the targets around each (seconds for 2,000 targets on two cores when no complete
/// association exists), and a site's video sees a few dozen.
pub const MAX_TLS_TARGETS: usize = 5_000;

impl ScaleError {
    /// Whether the error says that nothing was found (no reconstructed targets, no association)
    /// rather than that an input is unusable.
    #[must_use]
    pub fn is_nothing_found(&self) -> bool {
        match self {
            ScaleError::TooFew { what, .. } => what.starts_with("reconstructed"),
            ScaleError::NoAssociation { .. } => true,
            ScaleError::Degenerate(_) | ScaleError::TooManyTls { .. } => false,
        }
    }
}

/// The paper's two-target scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TwoTargetScale {
    /// Indices of the two reconstructed targets.
    pub reconstructed: [usize; 2],
    /// Indices of their TLS targets.
    pub tls: [usize; 2],
    /// TLS distance (m).
    pub tls_distance: f64,
    /// Reconstructed distance (SfM units).
    pub reconstructed_distance: f64,
    /// `tls_distance / reconstructed_distance`.
    pub scale: f64,
    /// Its standard deviation from the TLS targets' a-priori σ (both coordinates' errors along
    /// the line between them: `scale·√2·σ/d`).
    pub scale_std: f64,
}

/// The least-squares similarity over every associated target.
#[derive(Clone, Debug, PartialEq)]
pub struct SimilarityScale {
    /// SfM frame → TLS frame.
    pub similarity: Similarity,
    /// Its scale.
    pub scale: f64,
    /// Scale standard deviation: `σ̂ / √Σ|x − x̄|²`, with `σ̂² = Σ|r|² / (3n − 7)`.
    pub scale_std: f64,
    /// RMS of the 3D residuals (m).
    pub rms_m: f64,
    /// Each associated target's residual length (m), in association order.
    pub residuals_m: Vec<f64>,
}

/// The outcome of [`estimate_scale`].
#[derive(Clone, Debug, PartialEq)]
pub struct ScaleEstimate {
    /// Associated (reconstructed, TLS) index pairs.
    pub associated: Vec<(usize, usize)>,
    /// The paper's scale.
    pub two_target: TwoTargetScale,
    /// The similarity over all associated targets (three or more).
    pub similarity: Option<SimilarityScale>,
    /// True when the association was assumed (exactly two TLS targets).
    pub assumed: bool,
}

impl ScaleEstimate {
    /// The scale to use and its standard deviation: the similarity's when there is one (it uses
    /// every target and measures its own precision), else the paper's two-target scale.
    #[must_use]
    pub fn best(&self) -> (f64, f64) {
        match &self.similarity {
            Some(s) => (s.scale, s.scale_std),
            None => (self.two_target.scale, self.two_target.scale_std),
        }
    }
}

/// Associates, then scales (module docs).
///
/// # Errors
///
/// [`ScaleError`] for fewer than two targets on either side, no consistent association of at
/// least three targets when three or more TLS targets are given, or coincident targets.
pub fn estimate_scale(
    reconstructed: &[ReconstructedTarget],
    tls: &[Point3<f64>],
    config: &ScaleConfig,
) -> Result<ScaleEstimate, ScaleError> {
    if tls.len() < 2 {
        return Err(ScaleError::TooFew {
            what: "TLS targets",
            found: tls.len(),
        });
    }
    if reconstructed.len() < 2 {
        return Err(ScaleError::TooFew {
            what: "reconstructed targets (matched in two or more frames)",
            found: reconstructed.len(),
        });
    }
    if tls.len() > MAX_TLS_TARGETS {
        return Err(ScaleError::TooManyTls {
            found: tls.len(),
            max: MAX_TLS_TARGETS,
        });
    }
    let by_views = most_views_first(reconstructed);
    let (associated, assumed) = if tls.len() == 2 {
        (vec![(by_views[0], 0), (by_views[1], 1)], true)
    } else {
        // Three pairs only say that two triangles are similar; a fourth target verifies it.
        let required = if tls.len().min(reconstructed.len()) >= 4 {
            4
        } else {
            3
        };
        let a = associate(reconstructed, &by_views, tls, config, required);
        if a.len() < required {
            return Err(ScaleError::NoAssociation {
                found: a.len(),
                required,
            });
        }
        (a, false)
    };
    let two_target = two_target_scale(reconstructed, tls, &associated, config)?;
    let similarity = if associated.len() >= 3 {
        similarity_scale(reconstructed, tls, &associated)
    } else {
        None
    };
    Ok(ScaleEstimate {
        associated,
        two_target,
        similarity,
        assumed,
    })
}

/// Indices of the targets, most views first (ties: lower index first).
fn most_views_first(targets: &[ReconstructedTarget]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..targets.len()).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(targets[i].views), i));
    order
}

/// Step 7: the two associated targets with the most views.
fn two_target_scale(
    reconstructed: &[ReconstructedTarget],
    tls: &[Point3<f64>],
    associated: &[(usize, usize)],
    config: &ScaleConfig,
) -> Result<TwoTargetScale, ScaleError> {
    let mut pairs = associated.to_vec();
    pairs.sort_by_key(|&(r, _)| (std::cmp::Reverse(reconstructed[r].views), r));
    let ((r0, t0), (r1, t1)) = (pairs[0], pairs[1]);
    let d_rec = (reconstructed[r0].point - reconstructed[r1].point).norm();
    let d_tls = (tls[t0] - tls[t1]).norm();
    if d_rec <= 0.0 || d_tls <= 0.0 || !(d_rec / d_tls).is_finite() {
        return Err(ScaleError::Degenerate(d_rec.min(d_tls)));
    }
    let scale = d_tls / d_rec;
    Ok(TwoTargetScale {
        reconstructed: [r0, r1],
        tls: [t0, t1],
        tls_distance: d_tls,
        reconstructed_distance: d_rec,
        scale,
        scale_std: scale * std::f64::consts::SQRT_2 * config.target_sigma_m / d_tls,
    })
}

/// The least-squares similarity and its scale's standard deviation.
fn similarity_scale(
    reconstructed: &[ReconstructedTarget],
    tls: &[Point3<f64>],
    associated: &[(usize, usize)],
) -> Option<SimilarityScale> {
    let from: Vec<Point3<f64>> = associated
        .iter()
        .map(|&(r, _)| reconstructed[r].point)
        .collect();
    let to: Vec<Point3<f64>> = associated.iter().map(|&(_, t)| tls[t]).collect();
    let sim = local_similarity(&from, &to)?;
    let residuals: Vec<f64> = from
        .iter()
        .zip(&to)
        .map(|(x, y)| (sim.apply(&x.coords) - y.coords).norm())
        .collect();
    let n = associated.len();
    let ss: f64 = residuals.iter().map(|r| r * r).sum();
    let mean = from.iter().map(|x| x.coords).sum::<Vector3<f64>>() / n as f64;
    // Spread of the reconstructed targets (SfM units).
    let spread: f64 = from.iter().map(|x| (x.coords - mean).norm_squared()).sum();
    let redundancy = 3 * n - 7;
    let scale_std = if redundancy > 0 && spread > 0.0 {
        (ss / redundancy as f64).sqrt() / spread.sqrt()
    } else {
        f64::NAN
    };
    Some(SimilarityScale {
        scale: sim.scale,
        scale_std,
        rms_m: (ss / n as f64).sqrt(),
        residuals_m: residuals,
        similarity: sim,
    })
}

/// A well-shaped triangle of seed targets: its vertices and sides `|ij|`, `|jk|`, `|ik|`.
struct SeedTriangle {
    points: [Point3<f64>; 3],
    dij: f64,
    djk: f64,
    dik: f64,
    /// Which seeds (positions in the seed list) it is made of, as a bit mask.
    seeds: u64,
}

/// The well-shaped triangles of the seeds (no side under a fifth of the longest), ordered so
/// that the seeds are used evenly: each next triangle is one whose seeds have been used least
/// so far (ties: the best-seen seeds first). A few triangles then avoid any one seed, which
/// lets [`search_is_complete`] stop early when one seed is a target the TLS list lacks.
fn seed_triangles(reconstructed: &[ReconstructedTarget], seeds: &[usize]) -> Vec<SeedTriangle> {
    let mut all = well_shaped_triangles(reconstructed, seeds);
    let mut used = vec![0usize; seeds.len()];
    let mut out = Vec::with_capacity(all.len());
    while !all.is_empty() {
        let uses = |t: &SeedTriangle| -> usize {
            (0..seeds.len())
                .filter(|&s| t.seeds >> s & 1 == 1)
                .map(|s| used[s])
                .sum()
        };
        let next = (0..all.len())
            .min_by_key(|&k| (uses(&all[k]), k))
            .unwrap_or(0);
        let t = all.remove(next);
        for (s, u) in used.iter_mut().enumerate() {
            *u += (t.seeds >> s & 1) as usize;
        }
        out.push(t);
    }
    out
}

/// Whether no association left unseen can match `best` targets: every association holds at
/// most `non_seeds` targets that are not seeds, so one with `best` targets holds at least
/// `best − non_seeds` seeds, and it has been seen if any triangle tried so far (`tried`, seed
/// bit masks) lies within those seeds (the triangle's TLS triple proposes it). Exact over the
/// subsets of at most 16 seeds; with more, only a complete association stops the search.
fn search_is_complete(tried: &[u64], n_seeds: usize, non_seeds: usize, best: usize) -> bool {
    let need = best.saturating_sub(non_seeds);
    if need < 3 || need > n_seeds {
        return need > n_seeds;
    }
    if n_seeds > 16 {
        return best >= n_seeds + non_seeds;
    }
    // A set of `need` seeds with no tried triangle inside is an association not yet seen.
    (0u64..1 << n_seeds)
        .filter(|m| m.count_ones() as usize == need)
        .all(|m| tried.iter().any(|&t| t & !m == 0))
}

/// The well-shaped triangles of the seeds, in the order of the seeds.
fn well_shaped_triangles(
    reconstructed: &[ReconstructedTarget],
    seeds: &[usize],
) -> Vec<SeedTriangle> {
    let mut out = Vec::new();
    for (si, &i) in seeds.iter().enumerate() {
        for (sj, &j) in seeds.iter().enumerate().skip(si + 1) {
            for (sk, &k) in seeds.iter().enumerate().skip(sj + 1) {
                let p = [i, j, k].map(|q| reconstructed[q].point);
                let (dij, djk, dik) = (
                    (p[0] - p[1]).norm(),
                    (p[1] - p[2]).norm(),
                    (p[0] - p[2]).norm(),
                );
                let longest = dij.max(djk).max(dik);
                if dij.min(djk).min(dik) < 0.2 * longest || longest <= 0.0 {
                    continue;
                }
                // Every ordered TLS triple is tried, so the vertices may be relabelled: the
                // longest side first (i–j), the shortest second (i–k), which makes the window
                // of candidate third vertices in `associate` as narrow as it can be.
                let sides = [(dij, [0, 1, 2]), (djk, [1, 2, 0]), (dik, [0, 2, 1])];
                let mut best = (f64::INFINITY, [0, 1, 2]);
                for (_, [a, b, c]) in sides {
                    for [x, y, z] in [[a, b, c], [b, a, c]] {
                        let d = |u: usize, v: usize| (p[u] - p[v]).norm();
                        // i = x, j = y, k = z: minimise |ik| / |ij|.
                        let ratio = d(x, z) / d(x, y);
                        if ratio < best.0 {
                            best = (ratio, [x, y, z]);
                        }
                    }
                }
                let [x, y, z] = best.1;
                let q = [p[x], p[y], p[z]];
                out.push(SeedTriangle {
                    points: q,
                    dij: (q[0] - q[1]).norm(),
                    djk: (q[1] - q[2]).norm(),
                    dik: (q[0] - q[2]).norm(),
                    seeds: 1 << si | 1 << sj | 1 << sk,
                });
            }
        }
    }
    out
}

/// The TLS targets in a k-d tree, relative to the first one (large survey coordinates), for
/// the consensus of each candidate similarity. `tree` is `None` when the tree cannot be built
/// (more coincident targets than a leaf holds): the targets are then scanned one by one.
struct TlsIndex<'a> {
    tls: &'a [Point3<f64>],
    tree: Option<ImmutableKdTree<f64, 3>>,
}

impl<'a> TlsIndex<'a> {
    fn new(tls: &'a [Point3<f64>]) -> Self {
        let origin = tls[0].coords;
        let entries: Vec<[f64; 3]> = tls.iter().map(|p| (p.coords - origin).into()).collect();
        TlsIndex {
            tls,
            tree: ImmutableKdTree::new_from_slice(&entries).ok(),
        }
    }

    /// The targets within `tol` of `y`, with their distances.
    fn within(&self, y: &Vector3<f64>, tol: f64, out: &mut Vec<(f64, usize)>) {
        out.clear();
        let near = |k: usize| {
            let d = (y - self.tls[k].coords).norm();
            (d <= tol).then_some((d, k))
        };
        match &self.tree {
            Some(tree) => {
                let q: [f64; 3] = (y - self.tls[0].coords).into();
                if !q.iter().all(|v| v.is_finite()) {
                    return;
                }
                let found = tree
                    .query(&q)
                    .within::<SquaredEuclidean<f64>>(tol * tol)
                    .execute();
                out.extend(found.iter().filter_map(|nb| near(nb.item as usize)));
            }
            None => out.extend((0..self.tls.len()).filter_map(near)),
        }
    }
}

/// A candidate association: its consensus and the triple that proposed it (for a total order
/// that does not depend on the thread count).
struct Candidate {
    pairs: Vec<(usize, usize)>,
    ss: f64,
    key: (usize, usize, usize, usize),
}

impl Candidate {
    /// Whether `self` beats `other`: more targets, then smaller residuals, then the earlier
    /// triangle and TLS triple.
    fn beats(&self, other: &Candidate) -> bool {
        self.pairs
            .len()
            .cmp(&other.pairs.len())
            .then_with(|| other.ss.total_cmp(&self.ss))
            .then_with(|| other.key.cmp(&self.key))
            .is_gt()
    }
}

/// The most seeds the association uses (their subsets are bit masks).
pub const MAX_SEEDS: usize = 64;

/// Seed triangles compared per pass over the TLS list (each pass sorts every target's
/// neighbours once); between passes the search may stop ([`associate`]).
const TRIANGLES_PER_PASS: usize = 8;

/// Consensus association (module docs): (reconstructed, TLS) pairs, at most one per target.
///
/// Every seed triangle (i, j, k) is compared with every TLS triple (a, b, c) whose sides agree
/// with it at the scale `|ab| / |ij|`, quadratic in the TLS list plus the candidates: per TLS
/// target `a`, the others sorted by their distance to it; walking `b` outwards, the `c` with
/// `|ac| ≈ |ab|·|ik|/|ij|` lie in a window of that list that only moves outwards (two
/// pointers), so each (a, triangle) costs one pass over the list plus the targets in its
/// windows. Each consistent triple's similarity is scored through a k-d tree of the TLS
/// targets. The triangles go in passes of [`TRIANGLES_PER_PASS`], their seeds used evenly
/// ([`seed_triangles`]), and the search stops once a pass has associated every reconstructed
/// target, or once no association as large as the best can have escaped the triangles tried
/// ([`search_is_complete`]). (Was cubic, every ordered TLS triple per triangle: a 2,008-target
/// list took more than a minute.)
fn associate(
    reconstructed: &[ReconstructedTarget],
    by_views: &[usize],
    tls: &[Point3<f64>],
    config: &ScaleConfig,
    required: usize,
) -> Vec<(usize, usize)> {
    let spacing = median_spacing(tls);
    let tol = config.tolerance * spacing;
    let seeds = &by_views[..by_views.len().min(config.seeds.clamp(3, MAX_SEEDS))];
    let triangles = seed_triangles(reconstructed, seeds);
    let index = TlsIndex::new(tls);
    let m = tls.len();
    let complete = reconstructed.len().min(m);
    // The best candidate with `a` as the image of vertex i, over triangles `first..`.
    let best_from = |a: usize, first: usize, pass: &[SeedTriangle]| -> Option<Candidate> {
        // The other TLS targets by distance to `a`.
        let mut around: Vec<(f64, usize)> = (0..m)
            .filter(|&b| b != a)
            .map(|b| ((tls[b] - tls[a]).norm(), b))
            .collect();
        around.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        let mut best: Option<Candidate> = None;
        for (t, tri) in pass.iter().enumerate() {
            let (mut lo, mut hi) = (0, 0);
            for &(dab, b) in &around {
                let s = dab / tri.dij;
                let want = s * tri.dik;
                while lo < around.len() && around[lo].0 < want - tol {
                    lo += 1;
                }
                hi = hi.max(lo);
                while hi < around.len() && around[hi].0 <= want + tol {
                    hi += 1;
                }
                // |bc| within tol of s·|jk|, compared squared (no square root per candidate).
                let want_bc = s * tri.djk;
                let (bc_lo, bc_hi) = ((want_bc - tol).max(0.0).powi(2), (want_bc + tol).powi(2));
                for &(_, c) in &around[lo..hi] {
                    let bc2 = (tls[b] - tls[c]).norm_squared();
                    if c == b || bc2 < bc_lo || bc2 > bc_hi {
                        continue;
                    }
                    let Some(sim) = local_similarity(&tri.points, &[tls[a], tls[b], tls[c]]) else {
                        continue;
                    };
                    let (pairs, ss) = consensus(reconstructed, &index, &sim, tol);
                    let candidate = Candidate {
                        pairs,
                        ss,
                        key: (first + t, a, b, c),
                    };
                    if best.as_ref().is_none_or(|b| candidate.beats(b)) {
                        best = Some(candidate);
                    }
                }
            }
        }
        best
    };
    let mut best: Option<Candidate> = None;
    let non_seeds = reconstructed.len() - seeds.len();
    for (k, pass) in triangles.chunks(TRIANGLES_PER_PASS).enumerate() {
        let first = k * TRIANGLES_PER_PASS;
        let found = (0..m)
            .into_par_iter()
            .filter_map(|a| best_from(a, first, pass))
            .reduce_with(|x, y| if y.beats(&x) { y } else { x });
        if let Some(f) = found
            && best.as_ref().is_none_or(|b| f.beats(b))
        {
            best = Some(f);
        }
        let tried: Vec<u64> = triangles[..first + pass.len()]
            .iter()
            .map(|t| t.seeds)
            .collect();
        // Below `required` the caller refuses the association anyway: what matters is whether an
        // unseen one could reach it.
        let count = best.as_ref().map_or(0, |b| b.pairs.len());
        if count >= complete
            || search_is_complete(&tried, seeds.len(), non_seeds, count.max(required))
        {
            break;
        }
    }
    let mut best = best.map_or_else(Vec::new, |c| c.pairs);
    // Refine on the whole consensus once (the triple's similarity carries the triple's noise).
    if best.len() >= 3 {
        let from: Vec<_> = best.iter().map(|&(r, _)| reconstructed[r].point).collect();
        let to: Vec<_> = best.iter().map(|&(_, t)| tls[t]).collect();
        if let Some(sim) = local_similarity(&from, &to) {
            let (pairs, _) = consensus(reconstructed, &index, &sim, tol);
            if pairs.len() >= best.len() {
                best = pairs;
            }
        }
    }
    best.sort_unstable();
    best
}

/// Umeyama around the first target point (large survey coordinates), returned in absolute
/// coordinates.
fn local_similarity(from: &[Point3<f64>], to: &[Point3<f64>]) -> Option<Similarity> {
    let origin = to.first()?.coords;
    let f: Vec<Vector3<f64>> = from.iter().map(|p| p.coords).collect();
    let t: Vec<Vector3<f64>> = to.iter().map(|p| p.coords - origin).collect();
    let mut sim = similarity_from_points(&f, &t)?;
    sim.translation += origin;
    Some(sim)
}

/// Targets the similarity brings within `tol` of a TLS target (each TLS target used once, the
/// closest claim wins) and their sum of squared distances.
fn consensus(
    reconstructed: &[ReconstructedTarget],
    index: &TlsIndex<'_>,
    sim: &Similarity,
    tol: f64,
) -> (Vec<(usize, usize)>, f64) {
    let mut claims: Vec<(f64, usize, usize)> = Vec::new();
    let mut near = Vec::new();
    for (r, t) in reconstructed.iter().enumerate() {
        index.within(&sim.apply(&t.point.coords), tol, &mut near);
        claims.extend(near.iter().map(|&(d, k)| (d, r, k)));
    }
    claims.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let (mut used_r, mut used_t) = (
        vec![false; reconstructed.len()],
        vec![false; index.tls.len()],
    );
    let mut pairs = Vec::new();
    let mut ss = 0.0;
    for (d, r, k) in claims {
        if !used_r[r] && !used_t[k] {
            used_r[r] = true;
            used_t[k] = true;
            pairs.push((r, k));
            ss += d * d;
        }
    }
    (pairs, ss)
}

/// Median distance of each TLS target to its nearest neighbour.
fn median_spacing(tls: &[Point3<f64>]) -> f64 {
    let mut nearest: Vec<f64> = tls
        .iter()
        .enumerate()
        .map(|(i, p)| {
            tls.iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, q)| (p - q).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    nearest.sort_by(f64::total_cmp);
    nearest[nearest.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Eight targets on a wall (y = 0) and the TLS frame: world + offset.
    fn wall_targets() -> Vec<Point3<f64>> {
        let xs = [-1.5, -0.9, -0.2, 0.4, 1.1, 1.6, -1.2, 0.8];
        let zs = [0.6, 2.1, 1.0, 2.4, 0.7, 1.9, 1.5, 1.3];
        xs.iter()
            .zip(&zs)
            .map(|(&x, &z)| Point3::new(x, 0.0, z))
            .collect()
    }

    fn sfm_of(world: &[Point3<f64>], scale: f64) -> (Similarity, Vec<Point3<f64>>) {
        let sim = Similarity {
            scale,
            rotation: UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
            translation: Vector3::new(4.0, -2.0, 7.5),
        };
        let p = world
            .iter()
            .map(|p| Point3::from(sim.apply(&p.coords)))
            .collect();
        (sim, p)
    }

    #[test]
    fn shuffled_noisy_targets_far_from_the_origin_are_associated_and_scaled() {
        let world = wall_targets();
        let offset = Vector3::new(5.0e5, 4.2e6, 310.0);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // TLS list: shuffled, 1 mm noise, large offset, plus one target the photos never saw.
        let order = [5usize, 2, 7, 0, 3, 6, 1, 4];
        let mut tls: Vec<Point3<f64>> = order
            .iter()
            .map(|&k| {
                let n = Vector3::from_fn(|_, _| 0.001 * (rng.random::<f64>() - 0.5) * 3.46);
                world[k] + offset + n
            })
            .collect();
        tls.push(Point3::new(2.2, 0.0, 0.4) + offset);
        // Reconstruction: in an SfM frame of scale 0.37, one target missing, views 3..10.
        let true_scale = 0.37;
        let (_, sfm) = sfm_of(&world, true_scale);
        let reconstructed: Vec<ReconstructedTarget> = (0..7)
            .map(|k| ReconstructedTarget {
                point: sfm[k],
                views: 3 + (k * 5) % 8,
            })
            .collect();
        let est = estimate_scale(&reconstructed, &tls, &ScaleConfig::default()).unwrap();
        assert!(!est.assumed);
        assert_eq!(est.associated.len(), 7);
        for &(r, t) in &est.associated {
            assert_eq!(order[t], r, "reconstructed {r} paired with TLS {t}");
        }
        let sim = est.similarity.as_ref().unwrap();
        // 1 mm target noise over ~1 m spread: scale to ~1e-3 relative.
        assert!((sim.scale * true_scale - 1.0).abs() < 2e-3, "{}", sim.scale);
        assert!(sim.scale_std > 0.0 && sim.scale_std < 2e-3 / true_scale);
        assert!(sim.rms_m < 0.002);
        // The paper's scale: the two targets with the most views, against their TLS distance.
        let two = est.two_target;
        let views = |r: usize| reconstructed[r].views;
        let most = reconstructed.iter().map(|t| t.views).max().unwrap();
        assert_eq!(views(two.reconstructed[0]), most);
        assert!((two.scale * true_scale - 1.0).abs() < 5e-3);
    }

    /// The association was cubic in the TLS list (2,008 targets took more than a
    /// minute, hours for the triples alone); it is now quadratic. Eight targets seen, hidden
    /// in a list of 2,008 with 2,000 others spread over a 60 m plant, 1 mm noise.
    #[test]
    fn eight_targets_among_2008_tls_targets_are_associated() {
        let world = wall_targets();
        let offset = Vector3::new(5.0e5, 4.2e6, 310.0);
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let mut tls: Vec<Point3<f64>> = (0..2000)
            .map(|_| {
                Point3::from(
                    offset
                        + Vector3::new(
                            rng.random_range(-30.0..30.0),
                            rng.random_range(0.5..30.0),
                            rng.random_range(0.0..12.0),
                        ),
                )
            })
            .collect();
        let at: Vec<usize> = (0..8).map(|k| 250 * k + 17).collect();
        for (k, &i) in at.iter().enumerate() {
            let n = Vector3::from_fn(|_, _| 0.001 * (rng.random::<f64>() - 0.5) * 3.46);
            tls.insert(i, world[k] + offset + n);
        }
        let (_, sfm) = sfm_of(&world, 0.37);
        let reconstructed: Vec<ReconstructedTarget> = sfm
            .iter()
            .enumerate()
            .map(|(k, &p)| ReconstructedTarget {
                point: p,
                views: 3 + k,
            })
            .collect();
        let est = estimate_scale(&reconstructed, &tls, &ScaleConfig::default()).unwrap();
        let expected: Vec<(usize, usize)> = at.iter().copied().enumerate().collect();
        assert_eq!(est.associated, expected);
        let scale = est.similarity.unwrap().scale;
        assert!((scale * 0.37 - 1.0).abs() < 2e-3, "scale {scale}");
        // Beyond the cap: a clear refusal, not hours of work.
        let long = vec![Point3::origin(); MAX_TLS_TARGETS + 1];
        assert!(matches!(
            estimate_scale(&reconstructed, &long, &ScaleConfig::default()),
            Err(ScaleError::TooManyTls {
                found: 5_001,
                max: 5_000
            })
        ));
    }

    #[test]
    fn the_search_stops_only_when_no_unseen_association_can_match_the_best() {
        let t = |a: u32, b: u32, c: u32| 1u64 << a | 1 << b | 1 << c;
        // Four seeds, all four triangles tried: any 3 seeds hold one.
        let all = [t(0, 1, 2), t(0, 1, 3), t(0, 2, 3), t(1, 2, 3)];
        assert!(search_is_complete(&all, 4, 0, 3));
        // Only the triangles with seed 0: {1, 2, 3} is unseen.
        assert!(!search_is_complete(&all[..3], 4, 0, 3));
        // Best 4 of 4 seeds: every set of 4 holds a tried triangle.
        assert!(search_is_complete(&all[..1], 4, 0, 4));
        // Two targets that are no seed: a best of 4 needs only 2 seeds, never certain.
        assert!(!search_is_complete(&all, 4, 2, 4));
        // More than the seeds can give: nothing unseen can tie.
        assert!(search_is_complete(&[], 4, 1, 6));
        // The spread order puts a triangle without seed 0 early.
        let world = wall_targets();
        let targets: Vec<ReconstructedTarget> = world
            .iter()
            .map(|&p| ReconstructedTarget { point: p, views: 5 })
            .collect();
        let seeds: Vec<usize> = (0..8).collect();
        let order = seed_triangles(&targets, &seeds);
        assert_eq!(order.len(), well_shaped_triangles(&targets, &seeds).len());
        assert!(order[..3].iter().any(|tri| tri.seeds & 1 == 0));
    }

    #[test]
    fn the_similarity_scale_spread_matches_its_standard_deviation() {
        let world = wall_targets();
        let (_, sfm) = sfm_of(&world, 2.0);
        let reconstructed: Vec<ReconstructedTarget> = sfm
            .iter()
            .map(|&p| ReconstructedTarget { point: p, views: 5 })
            .collect();
        let sigma = 0.002;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (mut scales, mut stds) = (Vec::new(), Vec::new());
        for _ in 0..400 {
            let tls: Vec<Point3<f64>> = world
                .iter()
                .map(|p| {
                    let n = Vector3::from_fn(|_, _| {
                        // Box–Muller.
                        let (u1, u2): (f64, f64) = (rng.random(), rng.random());
                        sigma * (-2.0 * (1.0 - u1).ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
                    });
                    p + n
                })
                .collect();
            let est = estimate_scale(&reconstructed, &tls, &ScaleConfig::default()).unwrap();
            let s = est.similarity.unwrap();
            scales.push(s.scale);
            stds.push(s.scale_std);
        }
        let mean = scales.iter().sum::<f64>() / 400.0;
        let spread = (scales.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / 399.0).sqrt();
        let predicted = (stds.iter().map(|s| s * s).sum::<f64>() / 400.0).sqrt();
        assert!((mean - 0.5).abs() < 3.0 * spread / 20.0, "mean {mean}");
        let ratio = spread / predicted;
        assert!((0.85..1.15).contains(&ratio), "spread/predicted {ratio}");
    }

    #[test]
    fn two_tls_targets_take_the_two_best_seen_targets() {
        let world = wall_targets();
        let (_, sfm) = sfm_of(&world, 1.0);
        let reconstructed: Vec<ReconstructedTarget> = sfm
            .iter()
            .enumerate()
            .map(|(k, &p)| ReconstructedTarget {
                point: p,
                views: if k == 2 || k == 6 { 9 } else { 4 },
            })
            .collect();
        // Given in the other order: the distance does not care.
        let tls = vec![world[6], world[2]];
        let est = estimate_scale(&reconstructed, &tls, &ScaleConfig::default()).unwrap();
        assert!(est.assumed && est.similarity.is_none());
        assert_eq!(est.two_target.reconstructed, [2, 6]);
        assert!((est.two_target.scale - 1.0).abs() < 1e-12);
        let d = (world[2] - world[6]).norm();
        assert!((est.two_target.scale_std - std::f64::consts::SQRT_2 * 0.001 / d).abs() < 1e-12);
    }

    #[test]
    fn a_foreign_target_list_or_a_single_target_is_refused() {
        let world = wall_targets();
        let (_, sfm) = sfm_of(&world, 1.0);
        let reconstructed: Vec<ReconstructedTarget> = sfm
            .iter()
            .map(|&p| ReconstructedTarget { point: p, views: 5 })
            .collect();
        // Random targets of another site.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let foreign: Vec<Point3<f64>> = (0..8)
            .map(|_| Point3::new(rng.random::<f64>() * 3.0, 0.0, rng.random::<f64>() * 2.5))
            .collect();
        assert!(matches!(
            estimate_scale(&reconstructed, &foreign, &ScaleConfig::default()),
            Err(ScaleError::NoAssociation { .. })
        ));
        assert!(matches!(
            estimate_scale(&reconstructed, &world[..1], &ScaleConfig::default()),
            Err(ScaleError::TooFew { found: 1, .. })
        ));
    }
}
