//! From edge chains to candidate ellipses: chains are split at corners and inflections (where
//! the gradient direction jumps or its rotation changes sense) into arcs; each arc that turns
//! far enough and is well fitted by an ellipse proposes one, with the polarity of its edge.
//! Arcs of one ellipse propose nearly the same ellipse and are merged here (arc grouping), and
//! again after refinement.

use nalgebra::Vector2;

use super::edges::Gradients;
use crate::geometry::conic::{Ellipse, fit_ellipse_direct};

/// A candidate ellipse from one or more arcs.
#[derive(Clone, Debug)]
pub struct Candidate {
    /// The algebraic fit of the arc pixels.
    pub ellipse: Ellipse,
    /// +1 if the image is brighter outside (a dark disc), −1 if brighter inside.
    pub polarity: f64,
    /// Arc pixels supporting it.
    pub support: usize,
    /// Pixels of the longest arc (whose ellipse stands for the group).
    pub best_arc: usize,
}

/// Gradient angle of chain pixel `i`.
fn angle(g: &Gradients, i: u32) -> f64 {
    let i = i as usize;
    f64::from(g.gy[i]).atan2(f64::from(g.gx[i]))
}

fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    (a + std::f64::consts::PI).rem_euclid(t) - std::f64::consts::PI
}

/// Splits a chain into arcs of monotonic turning without corners.
#[must_use]
pub fn split_arcs(g: &Gradients, chain: &[u32]) -> Vec<Vec<u32>> {
    const LAG: usize = 2;
    /// A jump of the gradient direction over two pixels beyond this is a corner.
    const CORNER_RAD: f64 = 0.9;
    let n = chain.len();
    if n < 2 * LAG + 2 {
        return vec![chain.to_vec()];
    }
    let ang: Vec<f64> = chain.iter().map(|&i| angle(g, i)).collect();
    let mut arcs = Vec::new();
    let mut start = 0;
    let mut sense = 0.0f64;
    let mut k = LAG;
    while k + LAG < n {
        let d = wrap(ang[k + LAG] - ang[k - LAG]);
        let corner = d.abs() > CORNER_RAD;
        // A reversal of the turning sense, ignoring the small wiggles of near-straight runs.
        let flips = d.abs() > 0.12 && sense != 0.0 && d.signum() != sense;
        if corner || flips {
            if k > start + 3 {
                arcs.push(chain[start..=k].to_vec());
            }
            start = k + 1;
            sense = 0.0;
            k += LAG + 1;
            continue;
        }
        if d.abs() > 0.12 {
            sense = d.signum();
        }
        k += 1;
    }
    if n > start + 3 {
        arcs.push(chain[start..].to_vec());
    }
    arcs
}

/// Total turning of the gradient along an arc (radians).
fn turning(g: &Gradients, arc: &[u32]) -> f64 {
    arc.windows(2)
        .map(|w| wrap(angle(g, w[1]) - angle(g, w[0])))
        .sum::<f64>()
        .abs()
}

/// Limits on candidate ellipses.
#[derive(Clone, Copy, Debug)]
pub struct CandidateLimits {
    /// Smallest semi-minor axis (px).
    pub min_semi_minor: f64,
    /// Largest semi-major axis (px).
    pub max_semi_major: f64,
    /// Smallest axis ratio b/a.
    pub min_axis_ratio: f64,
}

/// Candidate ellipses from arcs, merged when they propose the same ellipse. A chain that closes
/// on itself is first tried whole (small discs: pixel-quantised gradient directions make their
/// short arcs look like inflections), then its arcs.
#[must_use]
pub fn candidates(g: &Gradients, chains: &[Vec<u32>], limits: &CandidateLimits) -> Vec<Candidate> {
    let w = g.width;
    let mut out: Vec<Candidate> = Vec::new();
    for chain in chains {
        let (first, last) = (chain[0] as usize, chain[chain.len() - 1] as usize);
        let gap = ((first % w) as isize - (last % w) as isize)
            .abs()
            .max(((first / w) as isize - (last / w) as isize).abs());
        // Closed: the ends meet, or the gradient turns all the way round (a chain may overrun
        // its start along a doubled edge).
        // (A disc of semi-minor axis 2 px closes a chain of about 11 pixels.)
        let closed = chain.len() >= 8 && (gap <= 2 || turning(g, chain) >= 5.0);
        let whole = closed.then(|| chain.clone());
        for arc in whole.into_iter().chain(split_arcs(g, chain)) {
            propose(g, &arc, limits, w, &mut out);
        }
    }
    out
}

/// Adds the ellipse an arc proposes, if it turns far enough and fits.
fn propose(
    g: &Gradients,
    arc: &[u32],
    limits: &CandidateLimits,
    w: usize,
    out: &mut Vec<Candidate>,
) {
    // An arc must turn at least 80° to pin down an ellipse.
    if arc.len() < 6 || turning(g, arc) < 80f64.to_radians() {
        return;
    }
    let pts: Vec<Vector2<f64>> = arc
        .iter()
        .map(|&i| Vector2::new((i as usize % w) as f64 + 0.5, (i as usize / w) as f64 + 0.5))
        .collect();
    let Some(e) = fit_ellipse_direct(&pts) else {
        return;
    };
    if !(e.b >= 0.7 * limits.min_semi_minor
        && e.a <= limits.max_semi_major
        && e.b >= limits.min_axis_ratio * e.a)
    {
        return;
    }
    // Arc pixels lie within a pixel of the ellipse (distance ≈ algebraic value over the
    // gradient of the conic); a fifth may stray.
    let c = e.to_conic();
    let bad = pts
        .iter()
        .filter(|p| {
            let h = nalgebra::Vector3::new(p.x, p.y, 1.0);
            let ch = c * h;
            let grad = 2.0 * nalgebra::Vector2::new(ch.x, ch.y).norm();
            (h.dot(&ch) / grad.max(1e-300)).abs() > 1.0
        })
        .count();
    if bad * 5 > pts.len() {
        return;
    }
    // Polarity: the gradient points from dark to bright; outward means dark inside.
    let outward: f64 = arc
        .iter()
        .zip(&pts)
        .map(|(&i, p)| {
            let n = p - e.centre();
            f64::from(g.gx[i as usize]) * n.x + f64::from(g.gy[i as usize]) * n.y
        })
        .sum();
    let polarity = if outward > 0.0 { 1.0 } else { -1.0 };
    // Arc grouping: merge with an existing candidate proposing the same ellipse; the longest
    // arc's ellipse stands for the group.
    if let Some(c) = out
        .iter_mut()
        .find(|c| same(&c.ellipse, &e) && c.polarity == polarity)
    {
        if arc.len() > c.best_arc {
            c.ellipse = e;
            c.best_arc = arc.len();
        }
        c.support += arc.len();
    } else {
        out.push(Candidate {
            ellipse: e,
            polarity,
            support: arc.len(),
            best_arc: arc.len(),
        });
    }
}

/// Whether two ellipses are the same target: centres within a quarter of the smaller semi-minor
/// axis (at least 1 px) and semi-axes within 25 %.
#[must_use]
pub fn same(a: &Ellipse, b: &Ellipse) -> bool {
    let tol = (0.25 * a.b.min(b.b)).max(1.0);
    (a.centre() - b.centre()).norm() <= tol
        && (a.a / b.a - 1.0).abs() <= 0.25
        && (a.b / b.b - 1.0).abs() <= 0.25
}
