//! The bundle adjustment engine (layer 2): Levenberg–Marquardt over poses, 3D points and
//! intrinsics with the Schur complement on the points or the cameras, a free-network datum by
//! inner constraints, and the a-posteriori precision of the intrinsics (paper,
//! "Self-Calibrating Bundle Adjustment"; docs/math.md "Schur", "Datum").
//!
//! It is generic over the camera model ([`CameraModel`]): the `brown` model with shared
//! intrinsics for calibration ([`BrownModel`]), BAL's per-camera model for the public benchmark
//! ([`BalModel`]).
//!
//! * [`Problem`] says what is adjusted and what is fixed; [`AdjustConfig`] how to solve;
//!   [`AdjustSummary`] what happened (COLMAP's `BundleAdjustmentConfig` / `Options` /
//!   `Summary`).
//! * [`bundle_adjust`] runs the solver; [`free_network_datum`] moves the solution onto the
//!   inner-constraint datum of its initial points; [`precision`] computes σ0, the redundancy
//!   and the cofactor matrices (minimum trace for the points).

mod bal;
mod datum;
mod elimination;
mod model;
mod normal;
mod problem;
mod solver;

pub use bal::problem_from_bal;
pub use datum::{
    Precision, PrecisionRequest, Similarity, apply_similarity, correlation, free_network_datum,
    inner_constraint_basis, precision, similarity_from_points,
};
pub use model::{BalModel, BrownModel, CameraModel, ModelJacobians, RowHeight};
pub use problem::{FixedParameters, Observation, Problem};
pub use solver::bundle_adjust;

/// The loss applied to each observation's squared, weighted residual `s = w·|r|²`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Loss {
    /// Least squares: `ρ(s) = s`.
    Squared,
    /// Huber with threshold `b` (pixels): quadratic below `b`, linear above.
    Huber(f64),
    /// Cauchy with scale `b` (pixels): `ρ(s) = b²·ln(1 + s/b²)`.
    Cauchy(f64),
}

/// How to solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdjustConfig {
    /// Cap on step attempts (accepted or not), as Ceres counts iterations.
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction (Ceres'
    /// `function_tolerance`).
    pub function_tolerance: f64,
    /// Stop when the largest gradient component falls below this.
    pub gradient_tolerance: f64,
    /// Stop when the step is this small relative to the parameters.
    pub parameter_tolerance: f64,
    /// Initial trust-region radius μ (damping 1/μ); Ceres' default is 1e4.
    pub initial_trust_radius: f64,
    /// Loss on each observation.
    pub loss: Loss,
    /// Which unknowns each step's normal equations eliminate.
    pub elimination: Elimination,
}

/// Which unknowns the damped normal equations eliminate before the dense Cholesky (Ceres'
/// `linear_solver_ordering`): the same step either way, to rounding; the cost differs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Elimination {
    /// The one with fewer floating-point operations, counted from the problem's structure.
    #[default]
    Auto,
    /// The points: a reduced camera system of the shared intrinsics and every camera's block
    /// (BAL-like problems: few cameras, many points).
    Points,
    /// The cameras: a reduced point system of the shared intrinsics and every point (a
    /// calibration video: many frames with rolling-shutter motions, a hundred targets).
    Cameras,
}

impl Default for AdjustConfig {
    fn default() -> Self {
        AdjustConfig {
            max_iterations: 100,
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            initial_trust_radius: 1e4,
            loss: Loss::Squared,
            elimination: Elimination::Auto,
        }
    }
}

impl AdjustConfig {
    /// Checks every field.
    ///
    /// # Errors
    /// [`AdjustError::Config`] naming the field.
    pub fn validate(&self) -> Result<(), AdjustError> {
        let positive = |field: &'static str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(AdjustError::Config {
                    field,
                    value: v.to_string(),
                })
            }
        };
        positive("function_tolerance", self.function_tolerance)?;
        positive("gradient_tolerance", self.gradient_tolerance)?;
        positive("parameter_tolerance", self.parameter_tolerance)?;
        if !(self.initial_trust_radius.is_finite() && self.initial_trust_radius > 0.0) {
            return Err(AdjustError::Config {
                field: "initial_trust_radius",
                value: self.initial_trust_radius.to_string(),
            });
        }
        match self.loss {
            Loss::Huber(b) | Loss::Cauchy(b) if !(b.is_finite() && b > 0.0) => {
                Err(AdjustError::Config {
                    field: "loss",
                    value: b.to_string(),
                })
            }
            _ => Ok(()),
        }
    }
}

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Termination {
    /// A tolerance was met.
    Converged,
    /// The iteration cap was reached first.
    MaxIterations,
    /// No step could lower the cost (the trust region collapsed).
    NoProgress,
}

/// What a solve did.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct AdjustSummary {
    /// ½·Σρ at the start.
    pub initial_cost: f64,
    /// ½·Σρ at the end.
    pub final_cost: f64,
    /// Step attempts.
    pub iterations: usize,
    /// Accepted steps.
    pub successful_steps: usize,
    /// Why it stopped.
    pub termination: Termination,
    /// Observations with positive weight that were used.
    pub observations_used: usize,
    /// Observations left out because they could not be projected at the start.
    pub observations_dropped: usize,
    /// Largest gradient component at the last linearisation.
    pub max_gradient: f64,
}

impl AdjustSummary {
    /// Whether the solution can be used (COLMAP's `IsSolutionUsable`): it converged, or ran
    /// out of iterations after lowering the cost.
    #[must_use]
    pub fn is_usable(&self) -> bool {
        self.final_cost.is_finite()
            && (self.termination == Termination::Converged || self.final_cost < self.initial_cost)
    }
}

/// Why an adjustment could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AdjustError {
    /// The problem is inconsistent.
    #[error("invalid adjustment problem: {0}")]
    Invalid(String),
    /// Nothing to adjust.
    #[error("the adjustment has no observations")]
    NoObservations,
    /// A configuration field is out of range.
    #[error("adjustment setting `{field}` = {value} is out of range")]
    Config {
        /// The field.
        field: &'static str,
        /// Its value.
        value: String,
    },
    /// The normal equations are singular even with the datum fixed.
    #[error("the normal equations are singular: {0}")]
    Singular(String),
    /// Fewer observations than unknowns.
    #[error("no redundancy: {observations} coordinates for {unknowns} unknowns")]
    NoRedundancy {
        /// Observed coordinates.
        observations: usize,
        /// Unknowns minus the datum defect.
        unknowns: usize,
    },
}
