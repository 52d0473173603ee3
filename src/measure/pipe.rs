//! Measuring the pipe (paper, "Evaluation of Impact of Calibration on Pipe Reconstruction"): the
//! dense cloud brought to metres (and into the TLS frame when the targets give a similarity),
//! the pipe of interest fitted, its radius σ combining the fit's and the scale's, and with a TLS
//! scan the same pipe fitted there as the reference.

use nalgebra::Vector3;

use super::cloud::Cloud;
use super::cylinder::{CylinderConfig, CylinderError, CylinderFit, fit_cylinder_among};
use super::scale::ScaleEstimate;
use crate::adjust::Similarity;

/// How the cloud gets its metric scale.
#[derive(Clone, Debug, PartialEq)]
pub enum Scaling {
    /// A scale given by the user (`--scale`; 1 for an already metric cloud).
    Given(f64),
    /// From the targets against the TLS list.
    Targets(ScaleEstimate),
}

impl Scaling {
    /// The scale and its standard deviation.
    #[must_use]
    pub fn scale(&self) -> (f64, f64) {
        match self {
            Scaling::Given(s) => (*s, 0.0),
            Scaling::Targets(e) => e.best(),
        }
    }

    /// The transform applied to the cloud: the similarity into the TLS frame when the targets
    /// give one, else the scale alone (the cloud stays in its own, now metric, frame).
    #[must_use]
    pub fn transform(&self) -> Similarity {
        match self {
            Scaling::Targets(ScaleEstimate {
                similarity: Some(s),
                ..
            }) => s.similarity,
            _ => Similarity {
                scale: self.scale().0,
                ..Similarity::identity()
            },
        }
    }

    /// True when the measured cloud is in the TLS frame (so a TLS scan can be searched where
    /// the pipe was found).
    #[must_use]
    pub fn in_tls_frame(&self) -> bool {
        matches!(
            self,
            Scaling::Targets(ScaleEstimate {
                similarity: Some(_),
                ..
            })
        )
    }
}

/// A region of interest: points within `radius` of `centre` (in the measured frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    /// Centre.
    pub centre: Vector3<f64>,
    /// Radius.
    pub radius: f64,
}

impl Region {
    /// Whether `p` lies in the region.
    #[must_use]
    pub fn contains(&self, p: &Vector3<f64>) -> bool {
        (p - self.centre).norm() <= self.radius
    }
}

/// The measured pipe.
#[derive(Clone, Debug, PartialEq)]
pub struct PipeMeasurement {
    /// The fit in the measured frame (metres).
    pub fit: CylinderFit,
    /// Scale and its σ.
    pub scale: (f64, f64),
    /// Radius σ combining the fit's and the scale's:
    /// `√(σ_fit² + (r·σ_s/s)²)` (the two are independent).
    pub radius_std: f64,
    /// The transform applied to the cloud.
    pub transform: Similarity,
    /// The transformed finite points the fit's inlier indices refer to (the region of interest
    /// applied).
    pub points: Vec<Vector3<f64>>,
}

/// The reference radius from the TLS scan and the accuracy of the measurement.
#[derive(Clone, Debug, PartialEq)]
pub struct Reference {
    /// The TLS fit.
    pub fit: CylinderFit,
    /// Measured minus reference radius (m).
    pub accuracy: f64,
}

/// Transforms the finite points by `t` and keeps those in `region`.
#[must_use]
pub fn transformed_points(
    points: &[Vector3<f64>],
    t: &Similarity,
    region: Option<&Region>,
) -> Vec<Vector3<f64>> {
    points
        .iter()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .map(|p| t.apply(p))
        .filter(|p| region.is_none_or(|r| r.contains(p)))
        .collect()
}

/// Scales (and moves) the cloud, then fits the pipe.
///
/// # Errors
///
/// [`CylinderError`]: too few points, bad settings, or no cylinder.
pub fn measure_pipe(
    points: &[Vector3<f64>],
    scaling: &Scaling,
    region: Option<&Region>,
    config: &CylinderConfig,
) -> Result<PipeMeasurement, CylinderError> {
    let transform = scaling.transform();
    let points = transformed_points(points, &transform, region);
    let fit = fit_points(&points, config)?;
    let scale = scaling.scale();
    let r = fit.cylinder.radius;
    let radius_std = (fit.radius_std.powi(2) + (r * scale.1 / scale.0).powi(2)).sqrt();
    Ok(PipeMeasurement {
        fit,
        scale,
        radius_std,
        transform,
        points,
    })
}

/// Fits the best cylinder of finite points.
///
/// # Errors
///
/// As [`measure_pipe`].
pub fn fit_points(
    points: &[Vector3<f64>],
    config: &CylinderConfig,
) -> Result<CylinderFit, CylinderError> {
    let cloud = Cloud::new(points)?;
    let all: Vec<usize> = (0..cloud.len()).collect();
    fit_cylinder_among(&cloud, &all, config)
}

/// Fits the same pipe in the TLS scan: when the measurement is in the TLS frame, near the
/// measured axis (within three radii plus 0.2 m of the inliers' middle, axis within 10°);
/// otherwise (two targets: no rotation known) the best cylinder with a radius within 25 % of the
/// measured one.
///
/// # Errors
///
/// As [`measure_pipe`].
pub fn reference_fit(
    scan: &[Vector3<f64>],
    measured: &PipeMeasurement,
    same_frame: bool,
    config: &CylinderConfig,
) -> Result<Reference, CylinderError> {
    let c = &measured.fit.cylinder;
    let r = c.radius;
    let mut config = CylinderConfig {
        radius_min: 0.75 * r,
        radius_max: 1.25 * r,
        ..config.clone()
    };
    let region = if same_frame {
        config.axis_hint = Some((c.direction, 10f64.to_radians()));
        // The middle of the inliers, on the axis.
        let n = measured.fit.inlier_indices.len().max(1) as f64;
        let mean = measured
            .fit
            .inlier_indices
            .iter()
            .map(|&i| measured.points[i])
            .sum::<Vector3<f64>>()
            / n;
        let on_axis = c.point + (mean - c.point).dot(&c.direction) * c.direction;
        Some(Region {
            centre: on_axis,
            radius: 3.0 * r + 0.2,
        })
    } else {
        None
    };
    let points = transformed_points(scan, &Similarity::identity(), region.as_ref());
    let fit = fit_points(&points, &config)?;
    Ok(Reference {
        accuracy: r - fit.cylinder.radius,
        fit,
    })
}
