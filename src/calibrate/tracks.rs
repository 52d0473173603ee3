//! One target, one track: Algorithm 2's tracks consolidated with the poses' geometry.
//!
//! Where the two-view rule cannot tell neighbouring targets apart — a regular dot grid whose
//! rows run along the epipolar lines, small ellipses whose Quan δ hardly differs — mismatches
//! are chained, the robust triangulation rejects them, and one target ends up as several short
//! tracks in disjoint frames, or as a long track and two-view fragments that hold one of its
//! views and a neighbour's. With the frames' poses (an SfM model adjusted on its features, or
//! the calibration's own adjustment) a target seen in three or more views has a point that
//! says where it is in every other frame. [`consolidate`]:
//!
//! 1. **merges** tracks that are one target: one's point projects near an observation of the
//!    other (the candidates, found per frame rather than among all pairs of tracks), they share
//!    no frame, and the point triangulated from all their views reprojects within the gate in
//!    every view, before and after Algorithm 3 corrects the centres with partners from both
//!    (the epipolar consistency of every pair of their views, and more); or, when their points
//!    are unambiguously one target (closer to each other than a quarter of their distance to
//!    any other track), with each view's gate widened by the shift the merge brings to its
//!    own point's image, leaving out the shorter track's views that still do not fit;
//! 2. **grows** every track of three or more views, longest first, by the observations nearest
//!    its point in the frames it lacks, taking them from nobody or from a track of fewer views
//!    — a two-view track cannot be checked (two rays always have a closest point), and a
//!    shorter track holding a view that fits a longer one is the ghost of a periodic pattern
//!    (a point off the grid that lines up with one dot in some frames and its neighbour in
//!    others) — and keeps what reprojects within the gate after Algorithm 3 (a joined track's
//!    own views beyond the gate keep their excess, or it could never grow); a track left with
//!    one view is gone;
//! 3. merges again (growth removes the views that kept parts of one target apart), and grows
//!    and merges until nothing is claimed (at most four rounds).
//!
//! The gate is `√χ²₀.₉₉₉,₂ = 3.72` times the targets' robust σ ([`target_sigma`]), or the
//! 99.9th percentile of the long tracks' errors where pose errors make their tails heavier: a
//! true view fails it about once in a thousand, and two targets a few pixels apart never share
//! it. Nothing is split, and every step is deterministic (proposals in parallel, decisions in a
//! fixed order).

use nalgebra::{Point3, Vector2};
use rayon::prelude::*;
use serde::Serialize;

use super::eccentricity::EccentricityConfig;
use super::eccentricity::eccentricity_bound;
use super::track::{PairIndex, Track, TrackView, corrections, observations_of};
use super::views::{FrameCamera, TargetObservation};
use crate::geometry::triangulation::{depth, reprojection_rms, triangulate};
use crate::robust::{CHI2_MEDIAN_2DOF, SQRT_CHI2_999_2DOF, lower_median};

/// What [`consolidate`] changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Consolidation {
    /// The targets' robust σ (px) (0 when there was no track of three views).
    pub sigma_px: f64,
    /// The gate (px) views had to fit within.
    pub gate_px: f64,
    /// Tracks joined to another (each removes one track).
    pub merged: usize,
    /// Views added to tracks where their point projects.
    pub grown: usize,
    /// Tracks left with fewer than two views after giving views to longer ones, dropped.
    pub dissolved: usize,
}

/// The squared reprojection errors (px²) of the best centres of every view of the tracks with
/// at least `min_views` views about their triangulated points.
fn squared_residuals(tracks: &[Track], cameras: &[FrameCamera], min_views: usize) -> Vec<f64> {
    tracks
        .iter()
        .filter(|t| t.views.len() >= min_views)
        .flat_map(|t| {
            t.views.iter().filter_map(|v| {
                let uv = project(&cameras[v.frame], &t.point)?;
                Some((uv - v.best_centre()).norm_squared())
            })
        })
        .collect()
}

/// The robust σ (px, per coordinate) of the tracks' best centres about their triangulated
/// points, `sqrt(median r² / median χ²₂)` over the views of tracks with three or more views
/// (two views fit any point on their rays' common plane and say nothing); `None` without such
/// tracks.
#[must_use]
pub fn target_sigma(tracks: &[Track], cameras: &[FrameCamera]) -> Option<f64> {
    let mut r2 = squared_residuals(tracks, cameras, 3);
    if r2.is_empty() {
        return None;
    }
    Some((lower_median(&mut r2) / CHI2_MEDIAN_2DOF).sqrt())
}

/// The gate (px): `√χ²₀.₉₉₉,₂` times the targets' robust σ, or the 99.9th percentile of the
/// reprojection errors of tracks of five or more views when that is larger, up to
/// [`MAX_GATE_WIDENING`] times the Gaussian gate. Pose errors are shared by every target of a
/// frame, so the errors of a long track have heavier tails than independent noise of the
/// median's σ (measured on a hand-held video of a dot grid with poses from its SfM features:
/// the largest error of a true 36-view track 1.5× the Gaussian gate). The cap keeps the wrong
/// views of a first matching from widening the gate for more of them: on BoofCV's hexagonal
/// grid video the first iteration's percentile was a neighbour dot's distance (66 px for a
/// Gaussian gate of about 1 px), and the loop started from σ0 2.9 px.
fn gate(tracks: &[Track], cameras: &[FrameCamera], sigma: f64) -> f64 {
    let gaussian = SQRT_CHI2_999_2DOF * sigma.max(1e-3);
    let mut r2 = squared_residuals(tracks, cameras, 5);
    if r2.len() < 1000 {
        return gaussian;
    }
    let k = (r2.len() * 999) / 1000;
    let (_, q, _) = r2.select_nth_unstable_by(k, f64::total_cmp);
    q.sqrt().clamp(gaussian, MAX_GATE_WIDENING * gaussian)
}

/// How far the tails of long tracks may widen the gate beyond the Gaussian one ([`gate`]).
const MAX_GATE_WIDENING: f64 = 2.0;

/// Undistorted pixel of a world point in a frame, if it is in front.
fn project(camera: &FrameCamera, x: &Point3<f64>) -> Option<Vector2<f64>> {
    let p = camera.p();
    if depth(&p, x) <= 0.0 {
        return None;
    }
    let h = p * x.to_homogeneous();
    Some(Vector2::new(h.x / h.z, h.y / h.z))
}

/// The geometry the consolidation works with.
struct Context<'a> {
    cameras: &'a [FrameCamera],
    observations: &'a [Vec<TargetObservation>],
    pairs: &'a PairIndex<'a>,
    correction: Option<&'a EccentricityConfig>,
    gate: f64,
    size: (f64, f64),
}

impl Context<'_> {
    /// The eccentricity bound of an observation (px): how far its fitted centre may lie from
    /// the image of the target's centre.
    fn bound(&self, frame: usize, obs: usize) -> f64 {
        let e = &self.observations[frame][obs].ellipse;
        eccentricity_bound(e.a, e.b, self.cameras[frame].intrinsics.c)
    }

    /// Whether a view reprojects from `x` within the gate plus `allowance` (px): its fitted
    /// centre within them plus its eccentricity bound when Algorithm 3 did not correct it.
    fn fits_within(&self, v: &TrackView, x: &Point3<f64>, allowance: f64) -> bool {
        self.excess(v, x) <= allowance
    }

    /// How far (px) a view lies beyond the gate from `x` (negative within it; infinite behind
    /// the camera): its fitted centre's gate includes its eccentricity bound when Algorithm 3
    /// did not correct it.
    fn excess(&self, v: &TrackView, x: &Point3<f64>) -> f64 {
        let slack = if v.corrected.is_some() {
            0.0
        } else {
            self.bound(v.frame, v.obs)
        };
        project(&self.cameras[v.frame], x).map_or(f64::INFINITY, |uv| {
            (uv - v.best_centre()).norm() - self.gate - slack
        })
    }

    /// The allowance growth gives a track's own views ([`grow`]): a view beyond the gate at
    /// the track's point (a joined track's, [`Self::join_unambiguous`]) keeps its excess plus
    /// [`GROWTH_SLACK`] of the gate, so that the track can still take the observations where
    /// its point projects; views within the gate get none.
    fn own_allowance(&self, track: &Track) -> std::collections::HashMap<(usize, usize), f64> {
        track
            .views
            .iter()
            .filter_map(|v| {
                let e = self.excess(v, &track.point);
                (e > 0.0).then_some(((v.frame, v.obs), e + GROWTH_SLACK * self.gate))
            })
            .collect()
    }

    /// Two tracks in disjoint frames whose points are unambiguously one target (each of three
    /// or more views, closer to each other than [`UNAMBIGUOUS_FRACTION`] of their distance to
    /// any other track: `others` is the nearer of the two's distances to their nearest other
    /// track) made one: the longer track with the shorter one's views, each judged against
    /// the joint point with the gate widened by how far the joint point's image lies from
    /// its own track's point's image; while the joint track fails, the shorter track's view
    /// farthest from the longer track's point is left out (with the robust triangulation's
    /// rejects), down to the longer track as it was. The two points differ by errors that the frames of each share (pose errors,
    /// rolling shutter, a biased edge in some frames), not by noise alone: measured on
    /// BoofCV's hand-held dot-grid videos, 1.2–1.5 % of the dots stayed split into tracks of
    /// disjoint frames, their points 1.5–5 % of the dot spacing apart (up to 10 × their
    /// noise), the joint track's worst view at 1.01–1.1 × the gate.
    fn join_unambiguous(&self, a: &Track, b: &Track, others: f64) -> Option<Track> {
        if a.views.len() < 3
            || b.views.len() < 3
            || (a.point - b.point).norm() > UNAMBIGUOUS_FRACTION * others
        {
            return None;
        }
        let own: std::collections::HashMap<usize, Point3<f64>> = a
            .views
            .iter()
            .map(|v| (v.frame, a.point))
            .chain(b.views.iter().map(|v| (v.frame, b.point)))
            .collect();
        let shift = |v: &TrackView, x: &Point3<f64>| {
            let camera = &self.cameras[v.frame];
            match (
                own.get(&v.frame).and_then(|p| project(camera, p)),
                project(camera, x),
            ) {
                (Some(p), Some(q)) => (p - q).norm(),
                _ => 0.0,
            }
        };
        let (long, short) = if a.views.len() >= b.views.len() {
            (a, b)
        } else {
            (b, a)
        };
        // The shorter track's views, nearest the longer track's point first.
        let distance = |v: &TrackView| {
            project(&self.cameras[v.frame], &long.point)
                .map_or(f64::INFINITY, |uv| (uv - v.best_centre()).norm())
        };
        let mut extra: Vec<(f64, TrackView)> =
            short.views.iter().map(|v| (distance(v), *v)).collect();
        extra.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.frame.cmp(&y.1.frame)));
        let mut rejected = long.rejected.clone();
        rejected.extend(short.rejected.iter().copied());
        while !extra.is_empty() {
            let views: Vec<TrackView> = long
                .views
                .iter()
                .copied()
                .chain(extra.iter().map(|(_, v)| *v))
                .collect();
            if let Some(track) = self.solve_with(views, rejected.clone(), &shift) {
                return Some(track);
            }
            if let Some((_, left_out)) = extra.pop() {
                rejected.push((left_out.frame, left_out.obs));
            }
        }
        // None of the shorter track's views fits: the longer track stays as it was.
        Some(Track {
            rejected,
            ..long.clone()
        })
    }

    /// One target's views (no two in a frame, sorted by frame) corrected by Algorithm 3 and
    /// triangulated, if every view then fits the point.
    fn solve(&self, views: Vec<TrackView>, rejected: Vec<(usize, usize)>) -> Option<Track> {
        self.solve_with(views, rejected, &|_, _| 0.0)
    }

    /// [`Self::solve`] with an allowance (px) added to the gate of each view at a point.
    fn solve_with(
        &self,
        mut views: Vec<TrackView>,
        rejected: Vec<(usize, usize)>,
        allowance: &dyn Fn(&TrackView, &Point3<f64>) -> f64,
    ) -> Option<Track> {
        views.sort_by_key(|v| v.frame);
        if views.windows(2).any(|w| w[0].frame == w[1].frame) {
            return None;
        }
        let fit_all = |views: &[TrackView], point: &Point3<f64>| {
            views
                .iter()
                .all(|v| self.fits_within(v, point, allowance(v, point)))
        };
        let mut point = triangulate(&observations_of(&views, self.cameras, true))?;
        if !fit_all(&views, &point) {
            return None;
        }
        if let Some(eccentricity) = self.correction {
            let all = vec![true; views.len()];
            let c = corrections(
                &views,
                self.cameras,
                self.observations,
                self.pairs,
                &all,
                &point,
                eccentricity,
            );
            for (v, c) in views.iter_mut().zip(c) {
                v.set_correction(c);
            }
            point = triangulate(&observations_of(&views, self.cameras, true))?;
            if !fit_all(&views, &point) {
                return None;
            }
        }
        let rms_px = reprojection_rms(&observations_of(&views, self.cameras, true), &point);
        Some(Track {
            views,
            rejected,
            point,
            rms_px,
        })
    }

    /// Per frame and observation, the track holding it.
    fn owners(&self, tracks: &[Option<Track>]) -> Vec<Vec<Option<usize>>> {
        let mut owner: Vec<Vec<Option<usize>>> = self
            .observations
            .iter()
            .map(|o| vec![None; o.len()])
            .collect();
        for (t, track) in tracks.iter().enumerate() {
            for v in track.iter().flat_map(|t| &t.views) {
                owner[v.frame][v.obs] = Some(t);
            }
        }
        owner
    }

    /// The observations of frames `track` lacks that lie within the gate (plus their
    /// eccentricity bound) of its point's projection, nearest first per frame:
    /// `(frame, observation, distance)`.
    fn near(&self, track: &Track) -> Vec<(usize, usize, f64)> {
        let mut out = Vec::new();
        let (w, h) = self.size;
        for (f, camera) in self.cameras.iter().enumerate() {
            if track.views.iter().any(|v| v.frame == f) {
                continue;
            }
            let Some(uv) = project(camera, &track.point) else {
                continue;
            };
            if !(uv.x >= 0.0 && uv.y >= 0.0 && uv.x <= w && uv.y <= h) {
                continue;
            }
            let mut hits: Vec<(usize, usize, f64)> = self.observations[f]
                .iter()
                .enumerate()
                .filter_map(|(k, o)| {
                    let d = (o.centre() - uv).norm();
                    (d <= self.gate + self.bound(f, k)).then_some((f, k, d))
                })
                .collect();
            hits.sort_by(|a, b| a.2.total_cmp(&b.2).then(a.1.cmp(&b.1)));
            out.extend(hits);
        }
        out
    }
}

/// Each live track's two nearest other live tracks `(distance, track)` by their points,
/// nearest first (fewer when there are fewer tracks).
fn two_nearest(tracks: &[Option<Track>]) -> Vec<Vec<(f64, usize)>> {
    let live: Vec<(usize, Point3<f64>)> = tracks
        .iter()
        .enumerate()
        .filter_map(|(t, track)| Some((t, track.as_ref()?.point)))
        .collect();
    let mut out = vec![Vec::new(); tracks.len()];
    let found: Vec<(usize, Vec<(f64, usize)>)> = live
        .par_iter()
        .map(|&(t, x)| {
            let mut best: Vec<(f64, usize)> = Vec::with_capacity(3);
            for &(u, y) in &live {
                if u == t {
                    continue;
                }
                let d = (x - y).norm();
                if best.len() < 2 || d < best[1].0 {
                    best.push((d, u));
                    best.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                    best.truncate(2);
                }
            }
            (t, best)
        })
        .collect();
    for (t, best) in found {
        out[t] = best;
    }
    out
}

/// Merges tracks that are one target (module docs, step 1); returns the number of merges.
fn merge(ctx: &Context<'_>, tracks: &mut [Option<Track>]) -> usize {
    let owner = ctx.owners(tracks);
    let mut candidates: Vec<(usize, usize)> = tracks
        .par_iter()
        .enumerate()
        .filter_map(|(t, track)| Some((t, track.as_ref()?)))
        .flat_map_iter(|(t, track)| {
            ctx.near(track)
                .into_iter()
                .filter_map(|(f, k, _)| owner[f][k].filter(|&u| u != t))
                .map(move |u| (t.min(u), t.max(u)))
                .collect::<Vec<_>>()
        })
        .collect();
    // And the pairs whose points are unambiguously one target, whatever their images say
    // (their points may differ by more than the gate: [`Context::join_unambiguous`]).
    let nearest = two_nearest(tracks);
    for (t, near) in nearest.iter().enumerate() {
        if let [(d, u), (second, _), ..] = near[..]
            && d <= UNAMBIGUOUS_FRACTION * second
        {
            candidates.push((t.min(u), t.max(u)));
        }
    }
    candidates.sort_unstable();
    candidates.dedup();
    // The distance of `a` and `b` to their nearest other track.
    let others = |a: usize, b: usize| {
        let other = |t: usize, not: usize| {
            nearest[t]
                .iter()
                .find(|(_, u)| *u != not)
                .map_or(f64::INFINITY, |(d, _)| *d)
        };
        other(a, b).min(other(b, a))
    };
    let joined = |a: usize, b: usize, ta: &Track, tb: &Track| -> Option<Track> {
        let views: Vec<TrackView> = ta.views.iter().chain(&tb.views).copied().collect();
        let mut rejected = ta.rejected.clone();
        rejected.extend(tb.rejected.iter().copied());
        ctx.solve(views, rejected)
            .or_else(|| ctx.join_unambiguous(ta, tb, others(a, b)))
    };
    let mut scored: Vec<(f64, usize, usize)> = candidates
        .par_iter()
        .filter_map(|&(a, b)| {
            let j = joined(a, b, tracks[a].as_ref()?, tracks[b].as_ref()?)?;
            Some((j.rms_px, a, b))
        })
        .collect();
    scored.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let mut parent: Vec<usize> = (0..tracks.len()).collect();
    let root = |parent: &mut Vec<usize>, mut x: usize| {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    };
    let mut merged = 0;
    for (_, a, b) in scored {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        if ra == rb {
            continue;
        }
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        let (Some(ta), Some(tb)) = (&tracks[lo], &tracks[hi]) else {
            continue;
        };
        let Some(j) = joined(lo, hi, ta, tb) else {
            continue;
        };
        tracks[lo] = Some(j);
        tracks[hi] = None;
        parent[hi] = lo;
        merged += 1;
    }
    merged
}

/// Grows the tracks of three or more views (module docs, step 2); returns the views added and
/// the two-view tracks dissolved.
fn grow(ctx: &Context<'_>, tracks: &mut [Option<Track>]) -> (usize, usize) {
    let mut owner = ctx.owners(tracks);
    let mut order: Vec<usize> = (0..tracks.len())
        .filter(|&t| tracks[t].as_ref().is_some_and(|t| t.views.len() >= 3))
        .collect();
    order.sort_by_key(|&t| {
        (
            std::cmp::Reverse(tracks[t].as_ref().map_or(0, |t| t.views.len())),
            t,
        )
    });
    let proposals: Vec<Vec<(usize, usize, f64)>> = order
        .par_iter()
        .map(|&t| tracks[t].as_ref().map(|t| ctx.near(t)).unwrap_or_default())
        .collect();
    let (mut grown, mut dissolved) = (0, 0);
    for (&t, near) in order.iter().zip(proposals) {
        let Some(track) = tracks[t].clone() else {
            continue;
        };
        // The nearest observation per frame that is free or held by a track of fewer views
        // (a two-view track cannot be checked; a shorter track holding it is the ghost of a
        // periodic pattern, consistent with neighbouring targets in part of the frames).
        let mut claims: Vec<(usize, usize)> = Vec::new();
        let len = track.views.len();
        for (f, k, _) in near {
            if claims.iter().any(|c| c.0 == f) {
                continue;
            }
            let free = match owner[f][k] {
                None => true,
                Some(u) => u != t && tracks[u].as_ref().is_some_and(|u| u.views.len() < len),
            };
            if free {
                claims.push((f, k));
            }
        }
        if claims.is_empty() {
            continue;
        }
        // Keep the claims that fit after Algorithm 3; drop the worst one at a time.
        let own = ctx.own_allowance(&track);
        let allowance =
            |v: &TrackView, _: &Point3<f64>| own.get(&(v.frame, v.obs)).copied().unwrap_or(0.0);
        let mut grown_track = None;
        while !claims.is_empty() {
            let mut views = track.views.clone();
            views.extend(claims.iter().map(|&(f, k)| TrackView {
                frame: f,
                obs: k,
                centre: ctx.observations[f][k].centre(),
                corrected: None,
                partner: None,
                roundness: None,
            }));
            if let Some(g) = ctx.solve_with(views, track.rejected.clone(), &allowance) {
                grown_track = Some(g);
                break;
            }
            // The claim farthest from the current point goes.
            let worst = claims
                .iter()
                .enumerate()
                .map(|(i, &(f, k))| {
                    let d = project(&ctx.cameras[f], &track.point).map_or(f64::INFINITY, |uv| {
                        (ctx.observations[f][k].centre() - uv).norm()
                    });
                    (d, i)
                })
                .max_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
                .map(|(_, i)| i);
            match worst {
                Some(i) => {
                    claims.remove(i);
                }
                None => break,
            }
        }
        let Some(g) = grown_track else {
            continue;
        };
        for &(f, k) in &claims {
            if let Some(u) = owner[f][k] {
                let mut gone = false;
                if let Some(victim) = tracks[u].as_mut() {
                    victim.views.retain(|v| (v.frame, v.obs) != (f, k));
                    gone = victim.views.len() < 2;
                    if !gone
                        && let Some(x) =
                            triangulate(&observations_of(&victim.views, ctx.cameras, true))
                    {
                        victim.point = x;
                        victim.rms_px = reprojection_rms(
                            &observations_of(&victim.views, ctx.cameras, true),
                            &x,
                        );
                    }
                }
                if gone {
                    for v in tracks[u].iter().flat_map(|t| &t.views) {
                        owner[v.frame][v.obs] = None;
                    }
                    tracks[u] = None;
                    dissolved += 1;
                }
            }
            owner[f][k] = Some(t);
        }
        grown += claims.len();
        tracks[t] = Some(g);
    }
    (grown, dissolved)
}

/// Rounds of growth and merging at most (each round's claims can free the next's).
const GROWTH_ROUNDS: usize = 4;

/// Growth's extra allowance for a track's own views beyond the gate, as a fraction of the gate.
const GROWTH_SLACK: f64 = 0.25;

/// Two tracks' points closer to each other than this fraction of their distance to any other
/// track are one target ([`Context::join_unambiguous`]): two neighbouring targets of a grid
/// mistaken for one would be a whole spacing apart (a ratio of about 1).
const UNAMBIGUOUS_FRACTION: f64 = 0.25;

/// One target, one track (module docs): merges, then grows and merges again until nothing is
/// claimed. Returns the tracks (a
/// merged track in place of its first part, the others in their order) and what changed.
/// `correction` is Algorithm 3's configuration when the centres are corrected
/// ([`super::matching::MatchConfig::correction`]).
#[must_use]
pub fn consolidate(
    tracks: Vec<Track>,
    cameras: &[FrameCamera],
    observations: &[Vec<TargetObservation>],
    pairs: &PairIndex<'_>,
    image_size: (u32, u32),
    correction: Option<&EccentricityConfig>,
) -> (Vec<Track>, Consolidation) {
    let Some(sigma) = target_sigma(&tracks, cameras) else {
        return (tracks, Consolidation::default());
    };
    let gate_px = gate(&tracks, cameras, sigma);
    let ctx = Context {
        cameras,
        observations,
        pairs,
        correction,
        gate: gate_px,
        size: (f64::from(image_size.0), f64::from(image_size.1)),
    };
    let mut tracks: Vec<Option<Track>> = tracks.into_iter().map(Some).collect();
    let mut merged = merge(&ctx, &mut tracks);
    let (mut grown, mut dissolved) = (0, 0);
    for _ in 0..GROWTH_ROUNDS {
        let (g, d) = grow(&ctx, &mut tracks);
        if g == 0 {
            break;
        }
        grown += g;
        dissolved += d;
        merged += merge(&ctx, &mut tracks);
    }
    (
        tracks.into_iter().flatten().collect(),
        Consolidation {
            sigma_px: sigma,
            gate_px,
            merged,
            grown,
            dissolved,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::matching::MatchConfig;
    use crate::calibrate::views::observations;
    use crate::camera::Intrinsics;
    use crate::geometry::Rigid3;
    use crate::geometry::conic::{Ellipse, conic_of_circle};
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use rand::SeedableRng;

    /// A flat grid of 6 × 5 dots (radius 1 cm, spacing 3 cm) filmed by 12 frames moving along
    /// the grid's rows — the layout whose neighbours share epipolar lines — with ellipse
    /// centres off by σ = 0.05 px; `truth[d]` lists dot `d`'s (frame, observation) in every
    /// frame that sees it.
    type Scene = (
        Vec<FrameCamera>,
        Vec<Vec<TargetObservation>>,
        Vec<Vec<(usize, usize)>>,
    );

    fn grid_scene() -> Scene {
        grid_scene_shifted(&|_, _| (0.0, 0.0))
    }

    /// [`grid_scene`] with dot `d`'s ellipse in frame `f` moved by `shift(f, d)` (px).
    fn grid_scene_shifted(shift: &dyn Fn(usize, usize) -> (f64, f64)) -> Scene {
        let intrinsics = Intrinsics::pinhole(800.0, 320.0, 240.0);
        let dots: Vec<Vector3<f64>> = (0..5)
            .flat_map(|r| {
                (0..6).map(move |c| {
                    Vector3::new(0.03 * c as f64 - 0.075, 0.03 * r as f64 - 0.06, 0.0)
                })
            })
            .collect();
        let normal = Vector3::new(0.0, 0.0, -1.0);
        let cameras: Vec<FrameCamera> = (0..12)
            .map(|k| {
                let x = -0.12 + 0.022 * k as f64;
                let centre = Vector3::new(x, 0.01 * (k % 3) as f64, -0.45);
                // Turned towards the grid's centre, with some roll.
                let look = (-centre).normalize();
                let r = UnitQuaternion::rotation_between(&Vector3::z(), &look).unwrap()
                    * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.1 * k as f64);
                let rotation = r.inverse();
                FrameCamera {
                    intrinsics,
                    cam_from_world: Rigid3::from_parts(
                        Translation3::from(-(rotation * centre)),
                        rotation,
                    ),
                }
            })
            .collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut obs = Vec::new();
        let mut truth = vec![Vec::new(); dots.len()];
        for (f, cam) in cameras.iter().enumerate() {
            let ellipses: Vec<(usize, Ellipse)> = dots
                .iter()
                .enumerate()
                .filter_map(|(d, x)| {
                    let c = conic_of_circle(&cam.k(), &cam.cam_from_world, x, &normal, 0.01)?;
                    let mut e = Ellipse::from_conic(&c)?;
                    let (du, dv) = shift(f, d);
                    e.cx += du + 0.05 * crate::robust::standard_normal(&mut rng);
                    e.cy += dv + 0.05 * crate::robust::standard_normal(&mut rng);
                    (e.cx > 10.0 && e.cy > 10.0 && e.cx < 630.0 && e.cy < 470.0).then_some((d, e))
                })
                .collect();
            let o = observations(
                f,
                cam,
                &ellipses.iter().map(|(_, e)| *e).collect::<Vec<_>>(),
            );
            assert_eq!(o.len(), ellipses.len());
            for (k, (d, _)) in ellipses.iter().enumerate() {
                truth[*d].push((f, k));
            }
            obs.push(o);
        }
        (cameras, obs, truth)
    }

    fn track(
        views: &[(usize, usize)],
        cameras: &[FrameCamera],
        obs: &[Vec<TargetObservation>],
    ) -> Track {
        let views: Vec<TrackView> = views
            .iter()
            .map(|&(frame, k)| TrackView {
                frame,
                obs: k,
                centre: obs[frame][k].centre(),
                corrected: None,
                partner: None,
                roundness: None,
            })
            .collect();
        let point = triangulate(&observations_of(&views, cameras, true)).unwrap();
        let rms_px = reprojection_rms(&observations_of(&views, cameras, true), &point);
        Track {
            views,
            rejected: Vec::new(),
            point,
            rms_px,
        }
    }

    /// Split tracks are joined, a two-view fragment holding a view of one dot and one of its
    /// neighbour gives the first back and is dropped, views a track lacks are found where its
    /// point projects — and every output track is exactly one dot's views in every frame.
    #[test]
    fn split_and_fragmented_tracks_become_one_track_per_dot() {
        let (cameras, obs, truth) = grid_scene();
        assert!(
            truth.iter().all(|t| t.len() >= 8),
            "every dot in most frames"
        );
        let mut input = Vec::new();
        for (d, views) in truth.iter().enumerate() {
            match d {
                // Dot 0 in two halves (no frame in common).
                0 => {
                    let (a, b) = views.split_at(views.len() / 2);
                    input.push(track(a, &cameras, &obs));
                    input.push(track(b, &cameras, &obs));
                }
                // Dot 1 without its view in its fourth frame, which a two-view fragment holds
                // with dot 2's view in that dot's eighth frame.
                1 => {
                    let mut v = views.clone();
                    let lost = v.remove(3);
                    input.push(track(&v, &cameras, &obs));
                    let stolen = truth[2][7];
                    input.push(track(&[lost, stolen], &cameras, &obs));
                }
                2 => {
                    let mut v = views.clone();
                    v.remove(7);
                    input.push(track(&v, &cameras, &obs));
                }
                // Dot 3 with two views missing that nobody holds.
                3 => input.push(track(&views[2..], &cameras, &obs)),
                _ => input.push(track(views, &cameras, &obs)),
            }
        }
        let pairs = PairIndex::new(&[]);
        let config = MatchConfig::default();
        let (out, c) = consolidate(
            input,
            &cameras,
            &obs,
            &pairs,
            (640, 480),
            config.correction(),
        );
        assert_eq!(out.len(), truth.len(), "{c:?}");
        for t in &out {
            let mut views: Vec<(usize, usize)> = t.views.iter().map(|v| (v.frame, v.obs)).collect();
            views.sort_unstable();
            assert!(
                truth.contains(&views),
                "a track that is not one dot's views: {views:?}"
            );
        }
        assert_eq!(c.merged, 1, "{c:?}");
        assert_eq!(c.dissolved, 1, "{c:?}");
        assert_eq!(c.grown, 4, "dot 1, dot 2 and dot 3's two: {c:?}");
    }

    /// Tracks of two neighbouring dots in disjoint halves of the frames are not one target:
    /// each grows into its own dot's frames, neither takes the other.
    #[test]
    fn neighbours_in_disjoint_frames_are_not_merged() {
        let (cameras, obs, truth) = grid_scene();
        let (a, b) = (&truth[8], &truth[9]);
        let input = vec![
            track(&a[..a.len() / 2], &cameras, &obs),
            track(&b[b.len() / 2..], &cameras, &obs),
        ];
        let pairs = PairIndex::new(&[]);
        let (out, c) = consolidate(
            input,
            &cameras,
            &obs,
            &pairs,
            (640, 480),
            MatchConfig::default().correction(),
        );
        assert_eq!(c.merged, 0);
        let sets: Vec<Vec<(usize, usize)>> = out
            .iter()
            .map(|t| {
                let mut v: Vec<_> = t.views.iter().map(|v| (v.frame, v.obs)).collect();
                v.sort_unstable();
                v
            })
            .collect();
        assert_eq!(sets, vec![a.clone(), b.clone()]);
    }

    /// [`grid_scene`] with dot 7 moved by `shift` (px) in the odd frames, and the tracks a
    /// matching would leave: dot 7 split into its even and its odd frames' tracks (`input[0]`,
    /// `input[1]`), every other dot's whole track after them. With `leave_free`, the middle
    /// even view of dot 7 is in no track and is returned as `free`.
    struct HalvesOfDot7 {
        scene: Scene,
        odd: Vec<(usize, usize)>,
        free: Option<(usize, usize)>,
        input: Vec<Track>,
    }

    fn halves_of_dot_7(shift: (f64, f64), leave_free: bool) -> HalvesOfDot7 {
        let (cameras, obs, truth) = grid_scene_shifted(&|f, d| {
            if d == 7 && f % 2 == 1 {
                shift
            } else {
                (0.0, 0.0)
            }
        });
        let views = &truth[7];
        let mut even: Vec<(usize, usize)> =
            views.iter().copied().filter(|(f, _)| f % 2 == 0).collect();
        let odd: Vec<(usize, usize)> = views.iter().copied().filter(|(f, _)| f % 2 == 1).collect();
        let free = leave_free.then(|| even.remove(even.len() / 2));
        assert!(even.len() >= 3 && odd.len() >= 3);
        let mut input = vec![track(&even, &cameras, &obs), track(&odd, &cameras, &obs)];
        for (d, v) in truth.iter().enumerate() {
            if d != 7 {
                input.push(track(v, &cameras, &obs));
            }
        }
        HalvesOfDot7 {
            scene: (cameras, obs, truth),
            odd,
            free,
            input,
        }
    }

    /// One dot seen with a systematic offset in half of the frames (as a frame's pose error,
    /// rolling shutter or a biased edge would put it): the two halves' tracks are each
    /// consistent, their joint track is not within the gate, but their points are far closer
    /// to each other than to any other dot. They become one track of that dot, and nothing of
    /// another dot's views enters it.
    #[test]
    fn unambiguous_halves_of_one_dot_beyond_the_gate_become_one_track() {
        let HalvesOfDot7 {
            scene: (cameras, obs, truth),
            input,
            ..
        } = halves_of_dot_7((0.9, -0.6), false);
        let pairs = PairIndex::new(&[]);
        let config = MatchConfig::default();
        // Without the unambiguity rule the halves stay apart: their joint track does not fit.
        let ctx_gate = {
            let sigma = target_sigma(&input, &cameras).unwrap();
            gate(&input, &cameras, sigma)
        };
        let joint: Vec<TrackView> = input[0]
            .views
            .iter()
            .chain(&input[1].views)
            .copied()
            .collect();
        let x = triangulate(&observations_of(&joint, &cameras, true)).unwrap();
        let worst = joint
            .iter()
            .map(|v| (project(&cameras[v.frame], &x).unwrap() - v.best_centre()).norm())
            .fold(0.0, f64::max);
        assert!(worst > ctx_gate, "worst {worst} px, gate {ctx_gate} px");
        let (out, c) = consolidate(
            input,
            &cameras,
            &obs,
            &pairs,
            (640, 480),
            config.correction(),
        );
        assert_eq!(out.len(), truth.len(), "{c:?}");
        for t in &out {
            let mut v: Vec<(usize, usize)> = t.views.iter().map(|v| (v.frame, v.obs)).collect();
            v.sort_unstable();
            let dot = truth.iter().position(|tv| tv.contains(&v[0])).unwrap();
            assert!(v.iter().all(|x| truth[dot].contains(x)), "dot {dot}: {v:?}");
        }
    }

    /// A track joined from unambiguous halves keeps views beyond the gate: it still grows by
    /// the view of its dot that nobody holds (without its own views' allowance every growth
    /// of such a track failed on its own views, and on BoofCV's hexagonal video the dots' free
    /// views came and went between the loop's iterations, which never converged).
    #[test]
    fn a_joined_track_beyond_the_gate_still_grows() {
        let HalvesOfDot7 {
            scene: (cameras, obs, truth),
            odd,
            free,
            input,
        } = halves_of_dot_7((0.3, 0.0), true);
        let free = free.unwrap();
        let views = &truth[7];
        let pairs = PairIndex::new(&[]);
        let (out, c) = consolidate(
            input,
            &cameras,
            &obs,
            &pairs,
            (640, 480),
            MatchConfig::default().correction(),
        );
        assert_eq!(out.len(), truth.len(), "{c:?}");
        let dot7 = out
            .iter()
            .find(|t| t.views.iter().any(|v| (v.frame, v.obs) == odd[0]))
            .unwrap();
        let mut v: Vec<(usize, usize)> = dot7.views.iter().map(|v| (v.frame, v.obs)).collect();
        v.sort_unstable();
        assert!(v.iter().all(|x| views.contains(x)), "{v:?}");
        // Joined with views beyond the gate, as the unambiguity rule allows.
        let worst = dot7
            .views
            .iter()
            .map(|v| (project(&cameras[v.frame], &dot7.point).unwrap() - v.best_centre()).norm())
            .fold(0.0, f64::max);
        assert!(worst > c.gate_px, "worst {worst} px, gate {} px", c.gate_px);
        assert!(
            v.contains(&free),
            "the free view {free:?} not taken: {v:?} ({c:?})"
        );
    }
}
