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
//!    (the epipolar consistency of every pair of their views, and more);
//! 2. **grows** every track of three or more views, longest first, by the observations nearest
//!    its point in the frames it lacks, taking them from nobody or from a track of fewer views
//!    — a two-view track cannot be checked (two rays always have a closest point), and a
//!    shorter track holding a view that fits a longer one is the ghost of a periodic pattern
//!    (a point off the grid that lines up with one dot in some frames and its neighbour in
//!    others) — and keeps what reprojects within the gate after Algorithm 3; a track left with
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

use super::eccentricity::eccentricity_bound;
use super::matching::{MatchConfig, PairIndex, Track, TrackView, corrections, observations_of};
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
/// reprojection errors of tracks of five or more views when that is larger. Pose errors are
/// shared by every target of a frame, so the errors of a long track have heavier tails than
/// independent noise of the median's σ (measured on a hand-held video of a dot grid with poses
/// from its SfM features: the largest error of a true 36-view track 1.5× the Gaussian gate).
fn gate(tracks: &[Track], cameras: &[FrameCamera], sigma: f64) -> f64 {
    let gaussian = SQRT_CHI2_999_2DOF * sigma.max(1e-3);
    let mut r2 = squared_residuals(tracks, cameras, 5);
    if r2.len() < 1000 {
        return gaussian;
    }
    let k = (r2.len() * 999) / 1000;
    let (_, q, _) = r2.select_nth_unstable_by(k, f64::total_cmp);
    gaussian.max(q.sqrt())
}

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
    config: &'a MatchConfig,
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

    /// Whether a view reprojects from `x` within the gate (its fitted centre within the gate
    /// plus its eccentricity bound when Algorithm 3 did not correct it).
    fn fits(&self, v: &TrackView, x: &Point3<f64>) -> bool {
        let slack = if v.corrected.is_some() {
            0.0
        } else {
            self.bound(v.frame, v.obs)
        };
        project(&self.cameras[v.frame], x)
            .is_some_and(|uv| (uv - v.best_centre()).norm() <= self.gate + slack)
    }

    /// One target's views (no two in a frame, sorted by frame) corrected by Algorithm 3 and
    /// triangulated, if every view then fits the point.
    fn solve(&self, mut views: Vec<TrackView>, rejected: Vec<(usize, usize)>) -> Option<Track> {
        views.sort_by_key(|v| v.frame);
        if views.windows(2).any(|w| w[0].frame == w[1].frame) {
            return None;
        }
        let mut point = triangulate(&observations_of(&views, self.cameras, true))?;
        if !views.iter().all(|v| self.fits(v, &point)) {
            return None;
        }
        if self.config.correct_centres {
            let all = vec![true; views.len()];
            let c = corrections(
                &views,
                self.cameras,
                self.observations,
                self.pairs,
                &all,
                &point,
                &self.config.eccentricity,
            );
            for (v, c) in views.iter_mut().zip(c) {
                (v.corrected, v.partner) = c.map_or((None, None), |(c, p)| (Some(c), Some(p)));
            }
            point = triangulate(&observations_of(&views, self.cameras, true))?;
            if !views.iter().all(|v| self.fits(v, &point)) {
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
    candidates.sort_unstable();
    candidates.dedup();
    let joined = |a: &Track, b: &Track| -> Option<Track> {
        let views: Vec<TrackView> = a.views.iter().chain(&b.views).copied().collect();
        let mut rejected = a.rejected.clone();
        rejected.extend(b.rejected.iter().copied());
        ctx.solve(views, rejected)
    };
    let mut scored: Vec<(f64, usize, usize)> = candidates
        .par_iter()
        .filter_map(|&(a, b)| {
            let j = joined(tracks[a].as_ref()?, tracks[b].as_ref()?)?;
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
        let Some(j) = joined(ta, tb) else {
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
        let mut grown_track = None;
        while !claims.is_empty() {
            let mut views = track.views.clone();
            views.extend(claims.iter().map(|&(f, k)| TrackView {
                frame: f,
                obs: k,
                centre: ctx.observations[f][k].centre(),
                corrected: None,
                partner: None,
            }));
            if let Some(g) = ctx.solve(views, track.rejected.clone()) {
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

/// One target, one track (module docs): merges, then grows and merges again until nothing is
/// claimed. Returns the tracks (a
/// merged track in place of its first part, the others in their order) and what changed.
#[must_use]
pub fn consolidate(
    tracks: Vec<Track>,
    cameras: &[FrameCamera],
    observations: &[Vec<TargetObservation>],
    pairs: &PairIndex<'_>,
    image_size: (u32, u32),
    config: &MatchConfig,
) -> (Vec<Track>, Consolidation) {
    let Some(sigma) = target_sigma(&tracks, cameras) else {
        return (tracks, Consolidation::default());
    };
    let gate_px = gate(&tracks, cameras, sigma);
    let ctx = Context {
        cameras,
        observations,
        pairs,
        config,
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
                    e.cx += 0.05 * crate::sim::sfm::gaussian(&mut rng);
                    e.cy += 0.05 * crate::sim::sfm::gaussian(&mut rng);
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
        let (out, c) = consolidate(input, &cameras, &obs, &pairs, (640, 480), &config);
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
            &MatchConfig::default(),
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
}
