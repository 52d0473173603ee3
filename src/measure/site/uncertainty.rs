//! The radius σ the poses add: the re-adjusted poses drawn from their covariance
//! ([`POSE_SAMPLES`] Monte Carlo samples), the targets and the cloud re-triangulated through
//! each draw, the scale and the radius re-estimated; their spread is the poses' share of σ.

use nalgebra::{DMatrix, Point3, Vector3, Vector6};
use rayon::prelude::*;

use super::SiteRequest;
use super::retriangulate::{RetriangulatedCloud, triangulate_rays};
use super::scaling::{SiteScale, triangulate_target};
use crate::calibrate::poses::{RollingPoses, pose_covariance};
use crate::measure::pipe::{PipeMeasurement, Scaling};
use crate::measure::scale::ScaleEstimate;
use crate::robust::standard_normal as gaussian;

/// Samples of the poses' covariance drawn for the radius's pose σ ([`super::measure_site`]).
pub const POSE_SAMPLES: usize = 32;

/// The radius's σ from the poses' uncertainty, by Monte Carlo: `POSE_SAMPLES` draws of all the
/// poses from their joint covariance; per draw the
/// targets and the pipe's points (those within 3 RMSE of the fitted cylinder) triangulated
/// again, the scale or similarity re-estimated on the same association, and the cylinder
/// fitted again. Seeded: the same input gives the same σ. `None` without a covariance
/// ([`pose_covariance`]).
pub(super) fn pose_radius_std(
    t: &SiteScale,
    cloud: &RetriangulatedCloud,
    pipe: &PipeMeasurement,
    request: &SiteRequest,
) -> Option<f64> {
    use rand::SeedableRng;
    let cov = pose_covariance(&t.model, &t.poses)?;
    let draw = covariance_sampler(&cov)?;
    let nominal = Scaling::Targets(t.estimate.clone()).transform();
    let c = &pipe.fit.cylinder;
    let band = 3.0 * pipe.fit.rmse.max(1e-6);
    let near: Vec<usize> = (0..cloud.points.len())
        .filter(|&k| {
            let p = nominal.apply(&cloud.points[k]);
            request.region.as_ref().is_none_or(|r| r.contains(&p)) && c.residual(&p).abs() < band
        })
        .collect();
    if near.len() < 50 {
        return None;
    }
    let frames = &t.poses.a1.frames;
    let block = cov.nrows() / frames.len().max(1);
    let tls = &t.tls_points;
    let radii: Vec<f64> = (0..POSE_SAMPLES)
        .into_par_iter()
        .filter_map(|s| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5EED_0000 + s as u64);
            let delta = draw(&mut rng);
            let poses: Vec<crate::geometry::Rigid3> = frames
                .iter()
                .enumerate()
                .map(|(j, f)| {
                    let d = Vector6::from_fn(|r, _| delta[block * j + r]);
                    crate::geometry::pose::retract(&f.camera.cam_from_world, &d)
                })
                .collect();
            // With rolling-shutter motions the covariance has their steps after each pose's.
            let sampled = t.poses.rolling.as_ref().map(|r| RollingPoses {
                motions: r
                    .motions
                    .iter()
                    .enumerate()
                    .map(|(j, m)| match block {
                        12 => crate::camera::rolling::Motion {
                            angular: m.angular + Vector3::from_fn(|r, _| delta[block * j + 6 + r]),
                            linear: m.linear + Vector3::from_fn(|r, _| delta[block * j + 9 + r]),
                            ..*m
                        },
                        _ => *m,
                    })
                    .collect(),
                ..r.clone()
            });
            let rolling = sampled.as_ref();
            let targets: Vec<Option<Point3<f64>>> = t
                .tracks
                .iter()
                .map(|views| triangulate_target(views, &t.intrinsics, &|f| poses[f], rolling))
                .collect();
            let transform = resampled_transform(&t.estimate, &targets, tls)?;
            let points: Vec<Vector3<f64>> = near
                .iter()
                .filter_map(|&k| {
                    triangulate_rays(&cloud.rays[k], &|j| poses[j], rolling)
                        .map(|p| transform.apply(&p))
                })
                .collect();
            crate::measure::pipe::fit_points(&points, &request.cylinder)
                .ok()
                .map(|f| f.cylinder.radius)
        })
        .collect();
    if radii.len() < POSE_SAMPLES / 2 {
        return None;
    }
    let mean = radii.iter().sum::<f64>() / radii.len() as f64;
    let var = radii.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (radii.len() - 1) as f64;
    Some(var.sqrt())
}

/// A sampler of `N(0, cov)`: `V·√Λ·z` from the symmetric eigen-decomposition (the
/// free network's covariance is singular along its datum; negative round-off clamped).
#[allow(clippy::type_complexity)]
fn covariance_sampler(
    cov: &DMatrix<f64>,
) -> Option<impl Fn(&mut rand_chacha::ChaCha8Rng) -> nalgebra::DVector<f64>> {
    let n = cov.nrows();
    if n == 0 || cov.ncols() != n || cov.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let eigen = nalgebra::SymmetricEigen::new(cov.clone());
    let scale: Vec<f64> = eigen
        .eigenvalues
        .iter()
        .map(|l| l.max(0.0).sqrt())
        .collect();
    let vectors = eigen.eigenvectors;
    Some(move |rng: &mut rand_chacha::ChaCha8Rng| {
        let z = nalgebra::DVector::from_fn(n, |k, _| scale[k] * gaussian(rng));
        &vectors * z
    })
}

/// The scale (or similarity) of `estimate` re-estimated on the same association from moved
/// targets.
fn resampled_transform(
    estimate: &ScaleEstimate,
    targets: &[Option<Point3<f64>>],
    tls: &[Point3<f64>],
) -> Option<crate::adjust::Similarity> {
    match &estimate.similarity {
        Some(_) => {
            let origin = tls.first()?.coords;
            let (from, to): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = estimate
                .associated
                .iter()
                .filter_map(|&(r, k)| {
                    Some((
                        targets.get(r)?.as_ref()?.coords,
                        tls.get(k)?.coords - origin,
                    ))
                })
                .unzip();
            let mut sim = crate::adjust::similarity_from_points(&from, &to)?;
            sim.translation += origin;
            Some(sim)
        }
        None => {
            let [a, b] = estimate.two_target.reconstructed;
            let d = (targets.get(a)?.as_ref()? - targets.get(b)?.as_ref()?).norm();
            (d > 0.0).then(|| crate::adjust::Similarity {
                scale: estimate.two_target.tls_distance / d,
                ..crate::adjust::Similarity::identity()
            })
        }
    }
}
