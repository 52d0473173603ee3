//! The free-network datum by inner constraints on the object points (Luhmann et al. 2013,
//! §4.4.3.3; docs/math.md "Datum") and the a-posteriori precision.
//!
//! A self-calibrating network of images alone has a 7-parameter datum defect (3 translations,
//! 3 rotations, 1 scale). The inner constraints `Cᵀ·δx = 0` ask the object points not to move,
//! rotate or scale as a whole; with `B` the null space of the normal matrix `N` (the
//! infinitesimal similarity acting on every parameter) and `C` its point rows, the cofactor
//! matrix of the constrained solution is
//!
//! ```text
//! Q = (N + C·Cᵀ)⁻¹ − B·(CᵀB)⁻¹·(BᵀC)⁻¹·Bᵀ
//! ```
//!
//! which is the minimum-trace one for the points. Intrinsics are invariant under the datum, so
//! their cofactors come from the reduced camera system with any regular datum.

use faer::Par;
use faer::linalg::cholesky::llt;
use nalgebra::{DMatrix, Matrix3, Rotation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use super::model::CameraModel;
use super::normal::{
    Dims, Incidence, Rec, cholesky_scratch, faer_par, linearise, pinned_indices, view,
};
use super::problem::Problem;
use super::{AdjustError, Loss};
use crate::geometry::pose::{Rigid3, skew};

/// A similarity `x ↦ s·R·x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    /// Scale.
    pub scale: f64,
    /// Rotation.
    pub rotation: UnitQuaternion<f64>,
    /// Translation.
    pub translation: Vector3<f64>,
}

impl Similarity {
    /// The identity (scale 1, no rotation, no translation).
    #[must_use]
    pub fn identity() -> Self {
        Similarity {
            scale: 1.0,
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// Applies the similarity to a point.
    #[must_use]
    pub fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * x) + self.translation
    }
}

/// The least-squares similarity mapping `from` onto `to` (Umeyama 1991), `None` for fewer than
/// three points or a degenerate (collinear) set.
#[must_use]
pub fn similarity_from_points(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Option<Similarity> {
    let n = from.len();
    if n < 3 || to.len() != n {
        return None;
    }
    let nf = n as f64;
    let mf = from.iter().sum::<Vector3<f64>>() / nf;
    let mt = to.iter().sum::<Vector3<f64>>() / nf;
    let mut cov = Matrix3::zeros();
    let mut var_from = 0.0;
    for (a, b) in from.iter().zip(to) {
        let (da, db) = (a - mf, b - mt);
        cov += db * da.transpose();
        var_from += da.norm_squared();
    }
    cov /= nf;
    var_from /= nf;
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u.determinant() * v_t.determinant()) < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let sv = svd.singular_values;
    if sv[1] <= 1e-12 * sv[0] || var_from <= 0.0 {
        return None;
    }
    let r = u * d * v_t;
    let scale = (sv[0] * d[(0, 0)] + sv[1] * d[(1, 1)] + sv[2] * d[(2, 2)]) / var_from;
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let translation = mt - scale * (rotation * mf);
    Some(Similarity {
        scale,
        rotation,
        translation,
    })
}

/// Moves a whole network by a similarity of the world: points `X' = s·R·X + t`, poses so that
/// every image is unchanged (`R_c' = R_c·Rᵀ`, `t_c' = s·t_c − R_c'·t`), per-camera values in world units
/// scaled (a rolling shutter's ν).
pub fn apply_similarity<M: CameraModel>(problem: &mut Problem<M>, sim: &Similarity) {
    for x in &mut problem.points {
        *x = sim.apply(x);
    }
    for pose in &mut problem.cam_from_world {
        let rotation = pose.rotation * sim.rotation.inverse();
        let translation = sim.scale * pose.translation.vector - rotation * sim.translation;
        *pose = Rigid3::from_parts(translation.into(), rotation);
    }
    let n = problem.model.local_len();
    if n > 0 {
        for local in problem.local.chunks_mut(n) {
            problem.model.scale_local(local, sim.scale);
        }
    }
}

/// Puts an adjusted free network on the inner-constraint datum of `reference` (the points'
/// initial approximations): the similarity that best maps the adjusted points back onto the
/// reference is applied to the whole network, so the points as a whole neither moved, turned
/// nor scaled. Returns the similarity applied.
///
/// # Errors
/// [`AdjustError::Invalid`] for fewer than three points or a degenerate set.
pub fn free_network_datum<M: CameraModel>(
    problem: &mut Problem<M>,
    reference: &[Vector3<f64>],
) -> Result<Similarity, AdjustError> {
    let sim = similarity_from_points(&problem.points, reference).ok_or_else(|| {
        AdjustError::Invalid("the datum needs at least three non-collinear points".into())
    })?;
    apply_similarity(problem, &sim);
    Ok(sim)
}

/// The 7 columns of the infinitesimal similarity (translation, rotation about the points'
/// centroid, scale) acting on every parameter of the reduced system (shared intrinsics, then
/// per camera pose and per-camera intrinsics) followed, when `with_points`, by the points:
/// the null space of the normal matrix of a free network. Row-major, 7 values per parameter.
#[must_use]
pub fn inner_constraint_basis<M: CameraModel>(problem: &Problem<M>, with_points: bool) -> Vec<f64> {
    let dims = Dims::of(problem);
    let n = dims.n_r
        + if with_points {
            3 * problem.points.len()
        } else {
            0
        };
    let mut b = vec![0.0; n * 7];
    let n_pts = problem.points.len().max(1) as f64;
    let centroid = problem.points.iter().sum::<Vector3<f64>>() / n_pts;
    let cx = skew(&centroid);
    for (c, pose) in problem.cam_from_world.iter().enumerate() {
        let rc = pose.rotation.to_rotation_matrix().into_inner();
        let base = dims.dg + c * dims.dc;
        let rcx = rc * cx;
        let scale_col = rc * centroid + pose.translation.vector;
        for i in 0..3 {
            // δω = −R_c·ω
            for j in 0..3 {
                b[(base + i) * 7 + 3 + j] = -rc[(i, j)];
                // δt = −R_c·T − R_c·[X̄]×·ω + σ·(R_c·X̄ + t_c)
                b[(base + 3 + i) * 7 + j] = -rc[(i, j)];
                b[(base + 3 + i) * 7 + 3 + j] = -rcx[(i, j)];
            }
            b[(base + 3 + i) * 7 + 6] = scale_col[i];
        }
        if dims.nl > 0 {
            let mut direction = vec![0.0; dims.nl];
            problem
                .model
                .local_scale_direction(problem.local_of(c), &mut direction);
            for (k, d) in direction.iter().enumerate() {
                b[(base + 6 + k) * 7 + 6] = *d;
            }
        }
    }
    if with_points {
        for (p, x) in problem.points.iter().enumerate() {
            let d = x - centroid;
            let dx = skew(&d);
            let base = dims.n_r + 3 * p;
            for i in 0..3 {
                b[(base + i) * 7 + i] = 1.0;
                for j in 0..3 {
                    b[(base + i) * 7 + 3 + j] = -dx[(i, j)];
                }
                b[(base + i) * 7 + 6] = d[i];
            }
        }
    }
    b
}

/// What [`precision`] should compute beyond σ0 and the shared intrinsics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PrecisionRequest {
    /// The cofactors of the reduced system (intrinsics and poses).
    pub poses: bool,
    /// The minimum-trace 3×3 covariance of every point (dense over all parameters: for
    /// networks of a few thousand unknowns).
    pub points: bool,
}

/// A-posteriori precision of an adjusted free network.
#[derive(Clone, Debug, PartialEq)]
pub struct Precision {
    /// σ0 = sqrt(vᵀPv / r).
    pub sigma0: f64,
    /// Redundancy r = observed coordinates − unknowns + datum defect (7).
    pub redundancy: usize,
    /// Observations used.
    pub observations: usize,
    /// Covariance σ0²·Q of the shared intrinsics (rows and columns of fixed ones are zero).
    pub global_covariance: DMatrix<f64>,
    /// Covariance σ0²·Q of the reduced system (shared intrinsics, then each camera's pose and
    /// per-camera intrinsics), minimum trace over the cameras, when requested.
    pub reduced_covariance: Option<DMatrix<f64>>,
    /// Minimum-trace covariance of each point, when requested.
    pub point_covariance: Option<Vec<Matrix3<f64>>>,
}

impl Precision {
    /// Standard deviations of the shared intrinsics.
    #[must_use]
    pub fn global_std(&self) -> Vec<f64> {
        (0..self.global_covariance.nrows())
            .map(|k| self.global_covariance[(k, k)].max(0.0).sqrt())
            .collect()
    }

    /// Correlation coefficients of the shared intrinsics (0 where one is fixed).
    #[must_use]
    pub fn global_correlation(&self) -> DMatrix<f64> {
        correlation(&self.global_covariance)
    }
}

/// Correlation coefficients of a covariance matrix (0 rows for zero variances).
#[must_use]
pub fn correlation(cov: &DMatrix<f64>) -> DMatrix<f64> {
    let n = cov.nrows();
    DMatrix::from_fn(n, n, |i, j| {
        let d = (cov[(i, i)] * cov[(j, j)]).sqrt();
        if d > 0.0 { cov[(i, j)] / d } else { 0.0 }
    })
}

/// σ0, redundancy and cofactors of an adjusted free network (no pose may be fixed), linearised
/// at the current values with the squared loss.
///
/// # Errors
/// [`AdjustError::Invalid`] if a pose is fixed, [`AdjustError::NoRedundancy`], or
/// [`AdjustError::Singular`] when the network does not determine its unknowns (e.g. a point
/// seen once, an intrinsic with no leverage).
pub fn precision<M: CameraModel>(
    problem: &Problem<M>,
    request: PrecisionRequest,
) -> Result<Precision, AdjustError> {
    problem.validate()?;
    if !problem.fixed.poses.is_empty() {
        return Err(AdjustError::Invalid(
            "the free-network precision needs every pose free".into(),
        ));
    }
    let dims = Dims::of(problem);
    let inc = Incidence::new(problem);
    let n_obs = problem.observations.len();
    let mut jac = vec![0.0; n_obs * dims.stride];
    let valid: Vec<bool> = jac
        .par_chunks_mut(dims.stride)
        .enumerate()
        .map(|(o, rec)| linearise(problem, dims, o, Loss::Squared, rec))
        .collect();
    let used: Vec<usize> = (0..n_obs)
        .filter(|&o| valid[o] && problem.observations[o].weight > 0.0)
        .collect();
    let vtpv: f64 = used
        .iter()
        .map(|&o| {
            let r = &jac[o * dims.stride..o * dims.stride + 2];
            r[0] * r[0] + r[1] * r[1]
        })
        .sum();
    let coords = 2 * used.len();
    let unknowns = problem.num_free_parameters() - 7;
    if coords <= unknowns {
        return Err(AdjustError::NoRedundancy {
            observations: coords,
            unknowns,
        });
    }
    let redundancy = coords - unknowns;
    let sigma0 = (vtpv / redundancy as f64).sqrt();
    let pinned = pinned_indices(problem, dims);

    // Reduced system S = U − W V⁻¹ Wᵀ with no damping.
    let n_r = dims.n_r;
    let mut s = vec![0.0; n_r * n_r];
    reduced_normal(problem, dims, &inc, &jac, &mut s)?;
    let b_r = inner_constraint_basis(problem, false);
    let q_r = constrained_inverse(&s, n_r, &b_r, &b_r, &pinned)?;
    let s2 = sigma0 * sigma0;
    let dg = dims.dg;
    let global_covariance = DMatrix::from_fn(dg, dg, |i, j| s2 * q_r[i * n_r + j]);
    let reduced_covariance = request
        .poses
        .then(|| DMatrix::from_fn(n_r, n_r, |i, j| s2 * q_r[i * n_r + j]));

    let point_covariance = if request.points {
        let n_pts = problem.points.len();
        let n = n_r + 3 * n_pts;
        let mut nfull = vec![0.0; n * n];
        full_normal(problem, dims, &jac, &mut nfull);
        let b = inner_constraint_basis(problem, true);
        let mut c = b.clone();
        c[..n_r * 7].fill(0.0);
        let q = constrained_inverse(&nfull, n, &b, &c, &pinned)?;
        Some(
            (0..n_pts)
                .map(|p| {
                    let k = n_r + 3 * p;
                    Matrix3::from_fn(|i, j| s2 * q[(k + i) * n + k + j])
                })
                .collect(),
        )
    } else {
        None
    };
    Ok(Precision {
        sigma0,
        redundancy,
        observations: used.len(),
        global_covariance,
        reduced_covariance,
        point_covariance,
    })
}

/// One observation's Jacobian columns over the reduced parameters: (index, both rows).
type JacobianColumns = Vec<(usize, [f64; 2])>;

/// The non-zero Jacobian columns of one observation over the reduced parameters (shared
/// intrinsics, then its camera's block), with their index.
fn reduced_columns(rec: &Rec<'_>, dims: Dims, camera: usize) -> JacobianColumns {
    let Dims { dg, dc, .. } = dims;
    let mut cols = Vec::with_capacity(dg + dc + 3);
    for g in 0..dg {
        cols.push((g, [rec.jg[g], rec.jg[dg + g]]));
    }
    for k in 0..dc {
        cols.push((dg + camera * dc + k, [rec.jc[k], rec.jc[dc + k]]));
    }
    cols
}

/// `S = U − W V⁻¹ Wᵀ` from the Jacobian records, dense row-major.
fn reduced_normal<M: CameraModel>(
    problem: &Problem<M>,
    dims: Dims,
    inc: &Incidence,
    jac: &[f64],
    s: &mut [f64],
) -> Result<(), AdjustError> {
    let Dims { n_r, stride, .. } = dims;
    let block = |o: usize| {
        let rec = view(&jac[o * stride..(o + 1) * stride], dims);
        let jp = [
            [rec.jp[0], rec.jp[1], rec.jp[2]],
            [rec.jp[3], rec.jp[4], rec.jp[5]],
        ];
        (
            reduced_columns(&rec, dims, problem.observations[o].camera),
            jp,
        )
    };
    for p in 0..problem.points.len() {
        let obs = inc.of_point(p);
        let mut v = Matrix3::zeros();
        let mut entries: Vec<(JacobianColumns, [[f64; 3]; 2])> = Vec::new();
        for &o in obs {
            let (cols, jp) = block(o);
            for i in 0..3 {
                for j in 0..3 {
                    v[(i, j)] += jp[0][i] * jp[0][j] + jp[1][i] * jp[1][j];
                }
            }
            // U contribution.
            for &(a, ja) in &cols {
                for &(b, jb) in &cols {
                    s[a * n_r + b] += ja[0] * jb[0] + ja[1] * jb[1];
                }
            }
            entries.push((cols, jp));
        }
        let Some(vinv) = v.try_inverse() else {
            return Err(AdjustError::Singular(format!(
                "point {p} is not determined by its {} observation(s)",
                obs.len()
            )));
        };
        // W columns of this point: Σ over its observations of J_cᵀ J_p, keyed by column.
        let mut w: Vec<(usize, Vector3<f64>)> = Vec::new();
        for (cols, jp) in &entries {
            for &(a, ja) in cols {
                let row = Vector3::from_fn(|k, _| ja[0] * jp[0][k] + ja[1] * jp[1][k]);
                match w.iter_mut().find(|(i, _)| *i == a) {
                    Some((_, r)) => *r += row,
                    None => w.push((a, row)),
                }
            }
        }
        for (a, wa) in &w {
            let y = vinv * wa;
            for (b, wb) in &w {
                s[a * n_r + b] -= y.dot(wb);
            }
        }
    }
    Ok(())
}

/// The full normal matrix `JᵀJ` over the reduced parameters and the points, dense row-major.
fn full_normal<M: CameraModel>(problem: &Problem<M>, dims: Dims, jac: &[f64], n_mat: &mut [f64]) {
    let Dims { n_r, stride, .. } = dims;
    let n = n_r + 3 * problem.points.len();
    for (o, obs) in problem.observations.iter().enumerate() {
        let rec = view(&jac[o * stride..(o + 1) * stride], dims);
        let mut cols = reduced_columns(&rec, dims, obs.camera);
        for k in 0..3 {
            cols.push((n_r + 3 * obs.point + k, [rec.jp[k], rec.jp[3 + k]]));
        }
        for &(a, ja) in &cols {
            for &(b, jb) in &cols {
                n_mat[a * n + b] += ja[0] * jb[0] + ja[1] * jb[1];
            }
        }
    }
}

/// `(N + C·Cᵀ)⁻¹ − B·(CᵀB)⁻¹·(BᵀC)⁻¹·Bᵀ` with pinned parameters removed (their rows and
/// columns are zero in the result). `b`, `c`: row-major n×7.
fn constrained_inverse(
    n_mat: &[f64],
    n: usize,
    b: &[f64],
    c: &[f64],
    pinned: &[usize],
) -> Result<Vec<f64>, AdjustError> {
    // Scale C to the size of N so that N + CCᵀ is well conditioned; the formula is invariant to
    // the scale of C.
    let trace: f64 = (0..n).map(|i| n_mat[i * n + i]).sum::<f64>() / n as f64;
    let c_norm2: f64 = c.iter().map(|v| v * v).sum::<f64>() / 7.0;
    let alpha = if c_norm2 > 0.0 {
        (trace / c_norm2).sqrt().max(1e-12)
    } else {
        1.0
    };
    let is_pinned = |k: usize| pinned.binary_search(&k).is_ok();
    let mut a = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            let mut v = n_mat[i * n + j];
            for k in 0..7 {
                v += alpha * alpha * c[i * 7 + k] * c[j * 7 + k];
            }
            a[i * n + j] = v;
        }
    }
    for &k in pinned {
        for j in 0..n {
            a[k * n + j] = 0.0;
            a[j * n + k] = 0.0;
        }
        a[k * n + k] = 1.0;
    }
    // Inverse by Cholesky and n right-hand sides.
    let mut inv = vec![0.0; n * n];
    for i in 0..n {
        inv[i * n + i] = 1.0;
    }
    let mut stack = cholesky_scratch(n);
    {
        let mut fa = faer::MatMut::from_column_major_slice_mut(&mut a, n, n);
        llt::factor::cholesky_in_place(
            fa.as_mut(),
            Default::default(),
            faer_par(),
            faer::dyn_stack::MemStack::new(&mut stack),
            Default::default(),
        )
        .map_err(|_| {
            AdjustError::Singular(
                "the normal matrix with inner constraints is not positive definite".into(),
            )
        })?;
        let mut stack2 = faer::dyn_stack::MemBuffer::new(
            llt::solve::solve_in_place_scratch::<f64>(n, n, Par::Seq),
        );
        let rhs = faer::MatMut::from_column_major_slice_mut(&mut inv, n, n);
        llt::solve::solve_in_place(
            fa.as_ref(),
            rhs,
            faer_par(),
            faer::dyn_stack::MemStack::new(&mut stack2),
        );
    }
    // CᵀB (7×7), scaled.
    let mut ctb = nalgebra::Matrix::<f64, nalgebra::U7, nalgebra::U7, _>::zeros();
    for i in 0..n {
        if is_pinned(i) {
            continue;
        }
        for r in 0..7 {
            for col in 0..7 {
                ctb[(r, col)] += alpha * c[i * 7 + r] * b[i * 7 + col];
            }
        }
    }
    let Some(k) = ctb.try_inverse() else {
        return Err(AdjustError::Singular(
            "the inner constraints do not fix the datum (degenerate point set)".into(),
        ));
    };
    let m = k * k.transpose();
    // Subtract B·M·Bᵀ (with (CᵀB)⁻¹(BᵀC)⁻¹ = K·Kᵀ).
    let bm: Vec<[f64; 7]> = (0..n)
        .map(|i| {
            let mut row = [0.0; 7];
            if !is_pinned(i) {
                for col in 0..7 {
                    row[col] = (0..7).map(|r| b[i * 7 + r] * m[(r, col)]).sum();
                }
            }
            row
        })
        .collect();
    for i in 0..n {
        for j in 0..n {
            if is_pinned(i) || is_pinned(j) {
                inv[i * n + j] = 0.0;
                continue;
            }
            let mut v = 0.0;
            for r in 0..7 {
                v += bm[i][r] * b[j * 7 + r];
            }
            inv[i * n + j] -= v;
        }
    }
    Ok(inv)
}
