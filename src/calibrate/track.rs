//! A matched target's track: its views in the frames ([`TrackView`], [`Track`]), Algorithm 3's
//! correction of those views (paper, Algorithm 3; [`super::eccentricity`]), and the index of
//! the overlapping pairs that gives Algorithm 3 its partners ([`PairIndex`]). Algorithm 2
//! ([`super::matching`]) builds the tracks; "one target, one track" ([`super::tracks`])
//! merges and grows them.

use std::collections::HashMap;

use nalgebra::{Point3, Vector2};

use super::eccentricity::{
    ConicView, EccentricityConfig, PairCameras, correct_target, eccentricity_bound,
};
use super::refine::PairGeometry;
use super::views::{FrameCamera, TargetObservation};
use crate::geometry::triangulation::Observation;

/// One view of a matched target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackView {
    /// Frame index.
    pub frame: usize,
    /// Index of the observation in its frame's list.
    pub obs: usize,
    /// The fitted ellipse centre (undistorted px).
    pub centre: Vector2<f64>,
    /// Algorithm 3's centre (undistorted px), if a partner qualified.
    pub corrected: Option<Vector2<f64>>,
    /// The partner frame of Algorithm 3.
    pub partner: Option<usize>,
    /// Algorithm 3's roundness of the target in its plane from this view
    /// ([`crate::geometry::quan::roundness_on_plane`]), if a partner qualified.
    pub roundness: Option<f64>,
}

impl TrackView {
    /// The best centre: corrected if available.
    #[must_use]
    pub fn best_centre(&self) -> Vector2<f64> {
        self.corrected.unwrap_or(self.centre)
    }
}

/// A matched target.
#[derive(Clone, Debug, PartialEq)]
pub struct Track {
    /// Its inlier views, in frame order.
    pub views: Vec<TrackView>,
    /// Chained views the robust triangulation rejected: (frame, observation).
    pub rejected: Vec<(usize, usize)>,
    /// Triangulated centre (from the best centres of the inlier views).
    pub point: Point3<f64>,
    /// RMS reprojection error of the best centres (px).
    pub rms_px: f64,
}

impl Track {
    /// The median of its views' roundness in the target's plane (Algorithm 3,
    /// [`TrackView::roundness`]), `None` when no view has one.
    #[must_use]
    pub fn roundness(&self) -> Option<f64> {
        let mut q: Vec<f64> = self.views.iter().filter_map(|v| v.roundness).collect();
        (!q.is_empty()).then(|| {
            0.5 * (crate::robust::lower_median(&mut q) + crate::robust::upper_median(&mut q))
        })
    }
}

/// The overlapping pairs by frame indices (for Algorithm 3's partners).
pub struct PairIndex<'a> {
    pairs: &'a [PairGeometry],
    index: HashMap<(usize, usize), usize>,
}

impl<'a> PairIndex<'a> {
    /// Indexes `pairs` by their frames.
    #[must_use]
    pub fn new(pairs: &'a [PairGeometry]) -> Self {
        PairIndex {
            pairs,
            index: pairs
                .iter()
                .enumerate()
                .map(|(k, p)| ((p.a, p.b), k))
                .collect(),
        }
    }

    /// Whether `(a, b)` is an overlapping pair.
    #[must_use]
    pub fn has(&self, a: usize, b: usize) -> bool {
        self.index.contains_key(&(a.min(b), a.max(b)))
    }

    /// The pair's local cameras ordered as `(a, b)`.
    fn cameras(&self, a: usize, b: usize, cameras: &[FrameCamera]) -> Option<PairCameras> {
        let (lo, hi) = (a.min(b), a.max(b));
        let pair = &self.pairs[*self.index.get(&(lo, hi))?];
        let l = pair.local_cameras(&cameras[lo], &cameras[hi])?;
        Some(if a == lo {
            (l.p_a, l.eye_a, l.p_b, l.eye_b)
        } else {
            (l.p_b, l.eye_b, l.p_a, l.eye_a)
        })
    }
}

/// Algorithm 3 on a track's views at `x`; `eligible` marks the views that may be partners.
pub(super) fn corrections(
    views: &[TrackView],
    cameras: &[FrameCamera],
    observations: &[Vec<TargetObservation>],
    pairs: &PairIndex,
    eligible: &[bool],
    x: &Point3<f64>,
    config: &EccentricityConfig,
) -> Vec<Option<CorrectedView>> {
    let conic_views: Vec<ConicView> = views
        .iter()
        .zip(eligible)
        .map(|(v, &ok)| {
            let o = &observations[v.frame][v.obs];
            ConicView {
                p: cameras[v.frame].p(),
                eye: cameras[v.frame].centre(),
                conic: o.conic,
                centre: v.centre,
                axis_ratio: o.ellipse.b / o.ellipse.a,
                bound: eccentricity_bound(o.ellipse.a, o.ellipse.b, cameras[v.frame].intrinsics.c),
                eligible: ok,
            }
        })
        .collect();
    // Partners with a robust F first (cameras consistent with it); views left without one use
    // the SfM poses' cameras (pose errors then tilt the plane a little: a weaker correction,
    // better than none — e.g. a target whose converging views share too few features).
    let available = |k: usize, l: usize| pairs.has(views[k].frame, views[l].frame);
    let pair = |k: usize, l: usize| pairs.cameras(views[k].frame, views[l].frame, cameras);
    let mut out = correct_target(&conic_views, x, config, &available, &pair);
    if out.iter().any(Option::is_none) {
        let global = |k: usize, l: usize| {
            Some((
                conic_views[k].p,
                conic_views[k].eye,
                conic_views[l].p,
                conic_views[l].eye,
            ))
        };
        let fallback = correct_target(&conic_views, x, config, &|_, _| true, &global);
        for (o, f) in out.iter_mut().zip(fallback) {
            if o.is_none() {
                *o = f;
            }
        }
    }
    out.into_iter()
        .map(|c| {
            c.map(|c| CorrectedView {
                centre: c.centre,
                partner: views[c.partner].frame,
                roundness: c.roundness,
            })
        })
        .collect()
}

/// What Algorithm 3 gives one view of a track.
#[derive(Clone, Copy, Debug)]
pub(super) struct CorrectedView {
    /// The image of the target's centre (undistorted px).
    pub centre: Vector2<f64>,
    /// The partner frame.
    pub partner: usize,
    /// The target's roundness in its plane from this view.
    pub roundness: Option<f64>,
}

impl TrackView {
    /// Sets (or clears) Algorithm 3's outcome for this view.
    pub(super) fn set_correction(&mut self, c: Option<CorrectedView>) {
        (self.corrected, self.partner, self.roundness) = match c {
            Some(c) => (Some(c.centre), Some(c.partner), c.roundness),
            None => (None, None, None),
        };
    }
}

pub(super) fn observations_of(
    views: &[TrackView],
    cameras: &[FrameCamera],
    corrected: bool,
) -> Vec<Observation> {
    views
        .iter()
        .map(|v| Observation {
            p: cameras[v.frame].p(),
            xy: if corrected { v.best_centre() } else { v.centre },
        })
        .collect()
}
