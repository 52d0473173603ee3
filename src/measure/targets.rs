//! The site's targets in the SfM frame (paper, pipe reconstruction steps 1–6): detected ellipses
//! undistorted with the frames' cameras, matched across views by Algorithm 2 with the pairs'
//! robust geometry (Algorithm 1), centres corrected by Algorithm 3, and triangulated.

use crate::calibrate::matching::{MatchConfig, Matching, match_targets};
use crate::calibrate::refine::PairGeometry;
use crate::calibrate::views::{FrameCamera, TargetObservation, observations};
use crate::geometry::conic::Ellipse;

use super::scale::ReconstructedTarget;

/// Matched and triangulated site targets.
#[derive(Clone, Debug, Default)]
pub struct SiteTargets {
    /// Per frame, its target observations in undistorted pixels.
    pub observations: Vec<Vec<TargetObservation>>,
    /// Algorithm 2's tracks (with Algorithm 3's centres and the triangulated points).
    pub matching: Matching,
}

impl SiteTargets {
    /// The triangulated targets with their view counts, in track order.
    #[must_use]
    pub fn reconstructed(&self) -> Vec<ReconstructedTarget> {
        self.matching
            .tracks
            .iter()
            .map(|t| ReconstructedTarget {
                point: t.point,
                views: t.views.len(),
            })
            .collect()
    }
}

/// Matches the detected ellipses of every frame (`detected[k]` in frame `k`'s observed pixels,
/// frames in the order of `cameras`) and triangulates the targets. `prior_sigma` is the
/// a-priori σ of a centre's reprojection (Algorithm 1's reprojection σ).
#[must_use]
pub fn match_site_targets(
    cameras: &[FrameCamera],
    pairs: &[PairGeometry],
    detected: &[Vec<Ellipse>],
    image_size: (u32, u32),
    prior_sigma: f64,
    config: &MatchConfig,
) -> SiteTargets {
    let observations: Vec<Vec<TargetObservation>> = cameras
        .iter()
        .zip(detected)
        .enumerate()
        .map(|(k, (camera, ellipses))| observations(k, camera, ellipses))
        .collect();
    let matching = match_targets(
        cameras,
        &observations,
        pairs,
        image_size,
        prior_sigma,
        config,
    );
    SiteTargets {
        observations,
        matching,
    }
}
