//! Where a flange interrupts a straight run: the pipe's surface stops for a few centimetres
//! and something wider than the pipe stands around its axis there.
//!
//! A flange pair bolted mid-run is 4–10 cm thick (two class-150 weld-neck flanges, ASME
//! B16.5) and shorter than any gap that ends a segment ([`super::NetworkConfig::gap_m`]):
//! without this test the runs on either side, on one axis with one radius, came out as one
//! segment running on through the joint (the piping's own joint, where a PCF or IFC model
//! needs two pipes and the flanges between). A gap in the inliers along the axis is a
//! **ring** when the points standing proud of the pipe's surface (1–15 cm out: a flange's
//! faces and rim) within the gap, those of one shell of proud distance (the rim, or a slice of
//! a face: [`RING_SHELL_M`]), surround the axis (at least [`RING_MIN_ARC_DEG`]) and are
//! confined to it: one side of the gap at least, over as long a stretch, holds at most a third
//! as many (a support, a beam or a wall beside the pipe goes on along it either way; a flange
//! does not, though a tank's shell may stand just beyond a nozzle's flange).

use nalgebra::Vector3;

use super::super::cloud::Cloud;
use super::super::cylinder::{Cylinder, filled_arc};
use super::super::shell::Shell;

/// Shortest gap in the inliers along the axis that can hold a flange (m): a single class-150
/// flange on a 1-inch pipe is 14 mm thick, its shadow adds to that.
pub(super) const RING_MIN_GAP_M: f64 = 0.012;
/// Nearest a ring's points stand off the pipe's surface (m): beyond the surface's band on the
/// noisiest scans (a flange's outside radius exceeds its pipe's by 4 cm or more).
const RING_MIN_PROUD_M: f64 = 0.01;
/// Farthest (m): a class-150 flange on a 12-inch pipe stands 12 cm proud of it.
const RING_MAX_PROUD_M: f64 = 0.15;
/// Fewest proud points in a gap for a ring.
const RING_MIN_POINTS: usize = 15;
/// Smallest arc about the axis a ring's points fill (degrees): a flange surrounds its pipe;
/// something passing beside it (a crossing pipe, a beam's edge) fills less.
const RING_MIN_ARC_DEG: f64 = 120.0;
/// Width of the shell of proud distances whose points must surround the axis (m): a flange's
/// rim lies at one radius, and so does a slice of its face; a bracket's or a beam's flat face
/// below a pipe lies at a distance that changes with the azimuth, so a shell holds a narrow arc
/// of it (all the points of a wall bracket's top under a small-bore line fill 120°).
const RING_SHELL_M: f64 = 0.008;
/// How many times as many proud points per metre the gap holds as either stretch beside it.
const RING_CONFINEMENT: f64 = 3.0;
/// The margin between a gap and the stretches beside it that it is compared with (m): a
/// flange's face lies at the gap's edge, within the noise.
const RING_MARGIN_M: f64 = 0.01;

/// A stretch of a run's inliers `(t, k)` with the axial positions of the rings at its ends.
pub(super) type Stretch<'a> = (&'a [(f64, usize)], Vec<f64>);

/// A point standing proud of a candidate's surface.
struct Proud {
    /// Its axial position (from the candidate's axis point).
    t: f64,
    /// Its radial unit vector.
    u: Vector3<f64>,
    /// How far it stands off the surface (m).
    proud: f64,
}

/// `run` (inliers `(t, k)` in axial order along `cyl`, `t` from `cyl.point`) split at the
/// rings in its gaps (module documentation): the stretches, each with the axial positions
/// (along `cyl`) of the rings at its ends.
pub(super) fn split_at_rings<'a>(
    cloud: &Cloud,
    cyl: &Cylinder,
    run: &'a [(f64, usize)],
) -> Vec<Stretch<'a>> {
    let gaps: Vec<usize> = run
        .windows(2)
        .enumerate()
        .filter(|(_, w)| w[1].0 - w[0].0 >= RING_MIN_GAP_M)
        .map(|(i, _)| i)
        .collect();
    if gaps.is_empty() {
        return vec![(run, Vec::new())];
    }
    // Each gap's window: the gap, and as long a stretch (at least 2 cm) beside it either side.
    let mut windows: Vec<[f64; 2]> = gaps
        .iter()
        .map(|&i| {
            let (a, b) = (run[i].0, run[i + 1].0);
            let w = (b - a).max(0.02);
            [a - RING_MARGIN_M - w, b + RING_MARGIN_M + w]
        })
        .collect();
    windows.sort_by(|x, y| x[0].total_cmp(&y[0]));
    windows.dedup_by(|next, kept| {
        let overlap = next[0] <= kept[1];
        if overlap {
            kept[1] = kept[1].max(next[1]);
        }
        overlap
    });
    let proud = proud_points(cloud, cyl, &windows);
    let (e1, e2) = cyl.cross_section_basis();
    let mut out = Vec::new();
    let mut from = 0;
    let mut rings_before: Vec<f64> = Vec::new();
    for &i in &gaps {
        let (a, b) = (run[i].0, run[i + 1].0);
        let w = (b - a).max(0.02);
        let mut inside: Vec<&Proud> = proud
            .iter()
            .filter(|p| (a - 0.5 * RING_MARGIN_M..=b + 0.5 * RING_MARGIN_M).contains(&p.t))
            .collect();
        if inside.len() < RING_MIN_POINTS {
            continue;
        }
        // The densest shell of RING_SHELL_M: a flange's rim, or a slice of its face.
        inside.sort_by(|x, y| x.proud.total_cmp(&y.proud));
        let mut shell = (0, 0);
        let mut j = 0;
        for i in 0..inside.len() {
            while j < inside.len() && inside[j].proud <= inside[i].proud + RING_SHELL_M {
                j += 1;
            }
            if j - i > shell.1 - shell.0 {
                shell = (i, j);
            }
        }
        let shell = &inside[shell.0..shell.1];
        if shell.len() < RING_MIN_POINTS
            || filled_arc(shell.iter().map(|p| p.u.dot(&e2).atan2(p.u.dot(&e1))))
                < RING_MIN_ARC_DEG.to_radians()
        {
            continue;
        }
        let beside = |lo: f64, hi: f64| proud.iter().filter(|p| (lo..hi).contains(&p.t)).count();
        let before = beside(a - RING_MARGIN_M - w, a - RING_MARGIN_M);
        let after = beside(b + RING_MARGIN_M, b + RING_MARGIN_M + w);
        // Per metre: the gap's window is its width and the margins' halves.
        let density = inside.len() as f64 / (b - a + RING_MARGIN_M);
        if density < RING_CONFINEMENT * before.min(after) as f64 / w {
            continue;
        }
        let ring = 0.5 * (a + b);
        rings_before.push(ring);
        out.push((&run[from..=i], std::mem::take(&mut rings_before)));
        rings_before.push(ring);
        from = i + 1;
    }
    out.push((&run[from..], rings_before));
    out
}

/// The cloud's points standing [`RING_MIN_PROUD_M`]–[`RING_MAX_PROUD_M`] off `cyl`'s surface
/// whose axial position lies in one of `windows` (sorted and disjoint, `t` from
/// `cyl.point`), in curve order. Runs of the Z-order whose box misses the shell are skipped.
fn proud_points(cloud: &Cloud, cyl: &Cylinder, windows: &[[f64; 2]]) -> Vec<Proud> {
    let local = Cylinder {
        point: cyl.point - cloud.origin,
        ..*cyl
    };
    let (lo, hi) = (cyl.radius + RING_MIN_PROUD_M, cyl.radius + RING_MAX_PROUD_M);
    let (t0, t1) = (windows[0][0], windows[windows.len() - 1][1]);
    let in_window = |t: f64| {
        let k = windows.partition_point(|w| w[1] < t);
        k < windows.len() && windows[k][0] <= t
    };
    let shell = Shell {
        point: local.point,
        direction: local.direction,
        inner: lo,
        outer: hi,
        along: Some((t0, t1)),
    };
    cloud.scan_shell(&shell, |pos| {
        let w = cloud.point_at(pos) - local.point;
        let t = w.dot(&local.direction);
        let off = w - local.direction * t;
        let rho = off.norm();
        ((lo..=hi).contains(&rho) && in_window(t)).then(|| Proud {
            t,
            u: off / rho,
            proud: rho - cyl.radius,
        })
    })
}
