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
    /// Whether that arc is a closed loop: a loop's ellipse stands for the group before any
    /// open arc's, however long (an open chain may run on into a neighbour's edge).
    pub best_closed: bool,
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

/// Splits a chain, given the gradient angles of its pixels, into arcs of monotonic turning
/// without corners: index ranges into the chain.
#[must_use]
pub fn split_arcs(ang: &[f64]) -> Vec<std::ops::Range<usize>> {
    const LAG: usize = 2;
    /// A jump of the gradient direction over two pixels beyond this is a corner.
    const CORNER_RAD: f64 = 0.9;
    let n = ang.len();
    if n < 2 * LAG + 2 {
        return std::iter::once(0..n).collect();
    }
    let mut arcs = Vec::new();
    let mut start = 0;
    let mut sense = 0.0f64;
    let mut k = LAG;
    while k + LAG < n {
        let d = wrap(ang[k + LAG] - ang[k - LAG]);
        let corner = d.abs() > CORNER_RAD;
        // A reversal of the turning sense, ignoring the small wiggles of near-straight runs.
        let flips = d.abs() > TURN_WIGGLE_RAD && sense != 0.0 && d.signum() != sense;
        if corner || flips {
            if k > start + 3 {
                arcs.push(start..k + 1);
            }
            start = k + 1;
            sense = 0.0;
            k += LAG + 1;
            continue;
        }
        if d.abs() > TURN_WIGGLE_RAD {
            sense = d.signum();
        }
        k += 1;
    }
    if n > start + 3 {
        arcs.push(start..n);
    }
    arcs
}

/// Signed turning of the gradient along pixels with these gradient angles (radians).
fn signed_turning(ang: &[f64]) -> f64 {
    ang.windows(2).map(|w| wrap(w[1] - w[0])).sum()
}

/// Total turning of the gradient along an arc with these gradient angles (radians).
fn turning(ang: &[f64]) -> f64 {
    signed_turning(ang).abs()
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

/// Fewest pixels of a chain that can close on themselves (a disc of semi-minor axis 2 px closes
/// a chain of about 11 pixels).
const MIN_LOOP_PX: usize = 8;

/// Least turning of an arc that pins down an ellipse: 80°.
const MIN_ARC_TURN_RAD: f64 = 80.0 * std::f64::consts::PI / 180.0;

/// Largest semi-major axis proposed by a short open chain tried whole: at a radius of 8 px
/// the curvature (a radian per 8 px) no longer reads as corners.
const SMALL_DISC_PX: f64 = 8.0;

/// Least turning of a short open chain tried whole: 120°, a third of the way round (the
/// textures of walls and floors have many short curved chains that turn less).
const MIN_SHORT_CHAIN_TURN_RAD: f64 = 120.0 * std::f64::consts::PI / 180.0;

/// Longest open chain also tried whole: the perimeter of a disc of radius 10 px.
const SHORT_CHAIN_PX: usize = 64;

/// A chain's ends, or a loop's, meet when they come within this many pixels (Chebyshev): the
/// linking steps over a pixel or two where an edge is faint.
const LOOP_GAP_PX: usize = 2;

/// Turning (rad) of a chain that has gone nearly all the way round (80 % of a turn): it is
/// closed, or a loop inside it is.
const CLOSED_TURN_RAD: f64 = 5.0;

/// Turning (rad) an open chain must reach before loops inside it are sought (about two thirds
/// of a turn).
const OPEN_CHAIN_LOOP_TURN_RAD: f64 = 4.0;

/// A change of the gradient direction over two pixels below this (rad) is a wiggle of a
/// near-straight run, not a turning sense.
const TURN_WIGGLE_RAD: f64 = 0.12;

/// Fewest pixels of an arc that proposes an ellipse (a conic needs five).
const MIN_ARC_PX: usize = 6;

/// A proposal's semi-minor axis may fall this far below the smallest wanted: the sub-pixel
/// refinement that follows decides on the size.
const PROPOSAL_MINOR_SLACK: f64 = 0.7;

/// Two ellipses are one target when their centres lie within this fraction of the smaller
/// semi-minor axis (at least [`SAME_CENTRE_MIN_PX`]) and their semi-axes within this fraction.
const SAME_TARGET_TOLERANCE: f64 = 0.25;
/// See [`SAME_TARGET_TOLERANCE`] (px).
const SAME_CENTRE_MIN_PX: f64 = 1.0;

/// Chebyshev distance between two pixels of a `w`-wide image.
fn pixel_gap(a: u32, b: u32, w: usize) -> usize {
    let (a, b) = (a as usize, b as usize);
    (a % w).abs_diff(b % w).max((a / w).abs_diff(b / w))
}

/// Signed turning of the gradient round a closed loop of pixels with these gradient angles, the
/// step from the last pixel back to the first included (±2π for a loop round a disc).
fn loop_turning(ang: &[f64]) -> f64 {
    signed_turning(ang) + wrap(ang[0] - ang[ang.len() - 1])
}

/// The loops inside a chain, as index ranges `[i, j]`: walking the chain, the first pixel that
/// comes back within 2 px of an earlier one (the nearest, then the earliest) at least
/// [`MIN_LOOP_PX`] pixels back closes a loop, if the gradient turns all the way round it; the
/// next loop starts after it. Between the dots of a dense grid (1.5 px apart in BoofCV's
/// hexagonal video) linking runs on from one disc's edge into its neighbour's: the chain holds
/// one disc's loop with a few stray pixels, or two loops joined, and neither closes end to end,
/// while a small disc's arcs are too short to propose it. `ang` holds the chain's gradient
/// angles; `sorted` is scratch space.
fn chain_loops(
    g: &Gradients,
    chain: &[u32],
    ang: &[f64],
    sorted: &mut Vec<(u32, usize)>,
) -> Vec<(usize, usize)> {
    let w = g.width as isize;
    sorted.clear();
    sorted.extend(chain.iter().enumerate().map(|(k, &p)| (p, k)));
    sorted.sort_unstable();
    let mut loops = Vec::new();
    let mut start = 0;
    for (j, &p) in chain.iter().enumerate() {
        if j + 1 < start + MIN_LOOP_PX {
            continue;
        }
        let mut best: Option<(usize, usize)> = None;
        let reach = LOOP_GAP_PX as isize;
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let q = p as isize + dy * w + dx;
                let Ok(q) = u32::try_from(q) else { continue };
                let Ok(k) = sorted.binary_search_by_key(&q, |&(pixel, _)| pixel) else {
                    continue;
                };
                let i = sorted[k].1;
                let gap = pixel_gap(p, q, g.width);
                if i >= start
                    && i + MIN_LOOP_PX <= j + 1
                    && gap <= LOOP_GAP_PX
                    && best.is_none_or(|b| (gap, i) < b)
                {
                    best = Some((gap, i));
                }
            }
        }
        if let Some((_, i)) = best
            && loop_turning(&ang[i..=j]).abs() >= CLOSED_TURN_RAD
        {
            loops.push((i, j));
            start = j + 1;
        }
    }
    loops
}

/// Candidate ellipses from arcs, merged when they propose the same ellipse. A chain that closes
/// on itself is first tried whole (small discs: pixel-quantised gradient directions make their
/// short arcs look like inflections), and so is every loop inside a chain that turns far enough
/// to hold one (linking may run from one dot's edge into a neighbour's 1.5 px away), and a short
/// open chain round a third or more of a small disc whose arcs are all too short; then its
/// arcs. A loop's ellipse stands for its group before any open arc's.
#[must_use]
pub fn candidates(g: &Gradients, chains: &[Vec<u32>], limits: &CandidateLimits) -> Vec<Candidate> {
    let w = g.width;
    let mut out: Vec<Candidate> = Vec::new();
    let (mut ang, mut sorted) = (Vec::new(), Vec::new());
    for chain in chains {
        let n = chain.len();
        ang.clear();
        ang.extend(chain.iter().map(|&i| angle(g, i)));
        let turns = turning(&ang);
        // Closed: the ends meet, or the gradient turns all the way round (a chain may overrun
        // its start along a doubled edge).
        let ends_meet = pixel_gap(chain[0], chain[n - 1], w) <= LOOP_GAP_PX;
        let closed = n >= MIN_LOOP_PX && (ends_meet || turns >= CLOSED_TURN_RAD);
        if closed {
            propose(g, chain, &ang, true, limits, &mut out);
        }
        // Loops inside: in a chain that turns far enough for one, unless its ends meet and it
        // turns less than one and a quarter times round (then the one loop is the whole chain).
        let loops = n >= MIN_LOOP_PX
            && if ends_meet {
                turns >= 2.5 * std::f64::consts::PI
            } else {
                turns >= OPEN_CHAIN_LOOP_TURN_RAD
            };
        if loops {
            for (i, j) in chain_loops(g, chain, &ang, &mut sorted) {
                if !(closed && i == 0 && j == n - 1) {
                    propose(g, &chain[i..=j], &ang[i..=j], true, limits, &mut out);
                }
            }
        }
        let arcs = split_arcs(&ang);
        // A short open chain round part of a small disc whose arcs all turn too little to
        // propose one (its curvature, a radian per 4 px at r = 4 px, reads as corners to
        // `split_arcs`) is tried whole, for a small ellipse only.
        if !closed
            && n <= SHORT_CHAIN_PX
            && turns >= MIN_SHORT_CHAIN_TURN_RAD
            && arcs
                .iter()
                .all(|a| turning(&ang[a.clone()]) < MIN_ARC_TURN_RAD)
        {
            let small = CandidateLimits {
                max_semi_major: limits.max_semi_major.min(SMALL_DISC_PX),
                ..*limits
            };
            propose(g, chain, &ang, false, &small, &mut out);
        }
        for arc in arcs {
            propose(g, &chain[arc.clone()], &ang[arc], false, limits, &mut out);
        }
    }
    out
}

/// Adds the ellipse an arc (pixels with gradient angles `ang`; `closed` for a loop) proposes,
/// if it turns far enough and fits.
fn propose(
    g: &Gradients,
    arc: &[u32],
    ang: &[f64],
    closed: bool,
    limits: &CandidateLimits,
    out: &mut Vec<Candidate>,
) {
    let w = g.width;
    if arc.len() < MIN_ARC_PX || turning(ang) < MIN_ARC_TURN_RAD {
        return;
    }
    let pts: Vec<Vector2<f64>> = arc
        .iter()
        .map(|&i| Vector2::new((i as usize % w) as f64 + 0.5, (i as usize / w) as f64 + 0.5))
        .collect();
    let Some(e) = fit_ellipse_direct(&pts) else {
        return;
    };
    if !(e.b >= PROPOSAL_MINOR_SLACK * limits.min_semi_minor
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
    // loop's, else the longest arc's, ellipse stands for the group.
    if let Some(c) = out
        .iter_mut()
        .find(|c| same(&c.ellipse, &e) && c.polarity == polarity)
    {
        if (closed, arc.len()) > (c.best_closed, c.best_arc) {
            c.ellipse = e;
            c.best_arc = arc.len();
            c.best_closed = closed;
        }
        c.support += arc.len();
    } else {
        out.push(Candidate {
            ellipse: e,
            polarity,
            support: arc.len(),
            best_arc: arc.len(),
            best_closed: closed,
        });
    }
}

/// Whether two ellipses are the same target: centres within a quarter of the smaller semi-minor
/// axis (at least 1 px) and semi-axes within 25 %.
#[must_use]
pub fn same(a: &Ellipse, b: &Ellipse) -> bool {
    let tol = (SAME_TARGET_TOLERANCE * a.b.min(b.b)).max(SAME_CENTRE_MIN_PX);
    (a.centre() - b.centre()).norm() <= tol
        && (a.a / b.a - 1.0).abs() <= SAME_TARGET_TOLERANCE
        && (a.b / b.b - 1.0).abs() <= SAME_TARGET_TOLERANCE
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 64;

    fn angles(g: &Gradients, chain: &[u32]) -> Vec<f64> {
        chain.iter().map(|&i| angle(g, i)).collect()
    }

    /// The edge pixels of a dark disc of radius `r` at `c` in angular order from `start` (rad),
    /// once round, each with the gradient of a dark disc's edge (outward, 1000 per unit).
    fn ring(g: &mut Gradients, c: (f64, f64), r: f64, start: f64) -> Vec<u32> {
        let mut pixels: Vec<u32> = Vec::new();
        for k in 0..256 {
            let t = start + std::f64::consts::TAU * f64::from(k) / 256.0;
            let (x, y) = ((c.0 + r * t.cos()).floor(), (c.1 + r * t.sin()).floor());
            let p = y as usize * W + x as usize;
            if pixels.last() != Some(&(p as u32)) && pixels.first() != Some(&(p as u32)) {
                pixels.push(p as u32);
            }
        }
        for &p in &pixels {
            let (x, y) = ((p as usize % W) as f64 + 0.5, (p as usize / W) as f64 + 0.5);
            let n = (x - c.0).hypot(y - c.1);
            g.gx[p as usize] = (1000.0 * (x - c.0) / n) as i16;
            g.gy[p as usize] = (1000.0 * (y - c.1) / n) as i16;
        }
        pixels
    }

    fn gradients() -> Gradients {
        Gradients {
            width: W,
            height: W,
            gx: vec![0; W * W],
            gy: vec![0; W * W],
            mag: vec![0; W * W],
        }
    }

    const LIMITS: CandidateLimits = CandidateLimits {
        min_semi_minor: 2.0,
        max_semi_major: 20.0,
        min_axis_ratio: 0.15,
    };

    /// Whether a dark-disc candidate is the same target ([`same`]) as the disc of radius `r` at
    /// `c`: what refinement starts from.
    fn proposes(cands: &[Candidate], c: (f64, f64), r: f64) -> bool {
        let disc = Ellipse {
            cx: c.0,
            cy: c.1,
            a: r,
            b: r,
            theta: 0.0,
        };
        cands
            .iter()
            .any(|k| k.polarity > 0.0 && same(&k.ellipse, &disc))
    }

    /// Two small dots 1 px apart whose edges were linked into one chain (once round the first,
    /// over to the second and once round it, as between the dots of BoofCV's dense hexagonal
    /// grid): the chain turns twice round, so it is no ellipse whole, and at r = 4 px its arcs
    /// are too short to propose one; each loop proposes its own dot.
    #[test]
    fn a_chain_round_two_touching_dots_proposes_each() {
        let mut g = gradients();
        let (a, b) = ((20.3, 30.6), (29.7, 30.4));
        let mut chain = ring(&mut g, a, 4.0, 0.0);
        chain.extend(ring(&mut g, b, 4.0, std::f64::consts::PI));
        assert!(turning(&angles(&g, &chain)) > 7.0);
        let cands = candidates(&g, &[chain], &LIMITS);
        assert!(proposes(&cands, a, 4.0), "{cands:?}");
        assert!(proposes(&cands, b, 4.0), "{cands:?}");
    }

    /// Part of a real dot's edge: the 13 pixels and Sobel directions (degrees) of a chain in
    /// frame 21 of BoofCV's hexagonal video (every 15th frame), shifted by (−290, −120); the
    /// rest of the dot's edge was linked into its neighbour's chain. It turns 174°, but at a
    /// curvature of a radian per 4 px `split_arcs` cuts it into pieces turning less than 80°;
    /// the short chain whole proposes the dot, whose refined ellipse in the frame is
    /// (316.85, 151.21), a 4.66, b 3.45 px, θ 1.171.
    #[test]
    fn part_of_a_small_dots_edge_proposes_it() {
        let mut g = gradients();
        let edge = [
            (29, 34, 47),
            (28, 35, 60),
            (27, 35, 86),
            (26, 35, 108),
            (25, 34, 133),
            (24, 33, 149),
            (23, 32, 158),
            (23, 31, 166),
            (23, 30, 178),
            (23, 29, -165),
            (23, 28, -157),
            (23, 27, -152),
            (24, 26, -138),
        ];
        let chain: Vec<u32> = edge
            .iter()
            .map(|&(x, y, deg): &(usize, usize, i32)| {
                let p = y * W + x;
                let t = f64::from(deg).to_radians();
                (g.gx[p], g.gy[p]) = ((1000.0 * t.cos()) as i16, (1000.0 * t.sin()) as i16);
                p as u32
            })
            .collect();
        let ang = angles(&g, &chain);
        assert!(turning(&ang) > 170f64.to_radians());
        assert!(
            split_arcs(&ang)
                .into_iter()
                .all(|a| turning(&ang[a]) < 80f64.to_radians())
        );
        let dot = Ellipse {
            cx: 26.85,
            cy: 31.21,
            a: 4.66,
            b: 3.45,
            theta: 1.171,
        };
        let cands = candidates(&g, &[chain], &LIMITS);
        assert!(
            cands
                .iter()
                .any(|k| k.polarity > 0.0 && same(&k.ellipse, &dot)),
            "{cands:?}"
        );
    }
}
