//! Levenberg–Marquardt with the Schur complement on the points (Triggs et al. 2000, §6.1;
//! docs/math.md "Schur"), the reduced camera system solved by faer's dense Cholesky, or on
//! the cameras ([`super::elimination`]) when that costs fewer operations.
//!
//! Each iteration linearises once, then tries damped steps until one is accepted:
//!
//! ```text
//! [U + λD_U   W      ] [δc]     [b_c]       S = U + λD_U − W (V + λD_V)⁻¹ Wᵀ
//! [Wᵀ         V + λD_V] [δp] = − [b_p]   →  S·δc = −b_c + W (V + λD_V)⁻¹ b_p
//!                                           δp = (V + λD_V)⁻¹ (−b_p − Wᵀ δc)
//! ```
//!
//! `c` holds the shared intrinsics first, then each camera's pose (6, the local perturbation of
//! [`crate::geometry::pose`]) and per-camera intrinsics. `D` is `diag(JᵀJ)` clamped to
//! `[1e-6, 1e32]`, `λ = 1/μ`, and the trust-region radius `μ` follows Ceres' rule
//! (`μ ← μ / max(1/3, 1 − (2ρ − 1)³)` on success, `μ ← μ/ν, ν ← 2ν` on failure), so iteration
//! counts compare with Ceres' `LEVENBERG_MARQUARDT` + `SPARSE_SCHUR`.
//!
//! Work is split across rayon tasks by output block (observations, points, rows of `S`), and
//! every sum is taken in a fixed order, so the result does not depend on the thread count.

use faer::dyn_stack::MemBuffer;
use nalgebra::{Matrix3, Vector3, Vector6};
use rayon::prelude::*;

use super::elimination::{CameraElimination, prefers_cameras};
use super::model::CameraModel;
use super::normal::{
    CHUNK, Dims, Incidence, Normal, assemble_reduced, cholesky_scratch, cholesky_solve, linearise,
    loss, pinned_indices, view,
};
use super::problem::Problem;
use super::{AdjustConfig, AdjustError, AdjustSummary, Elimination, Loss, Termination};
use crate::geometry::pose::{Rigid3, retract};

/// Ceres' `min_relative_decrease`.
const MIN_RELATIVE_DECREASE: f64 = 1e-3;
/// Bounds of the trust-region radius.
const MAX_RADIUS: f64 = 1e16;
const MIN_RADIUS: f64 = 1e-32;

/// The state being optimised.
#[derive(Clone)]
struct State {
    poses: Vec<Rigid3>,
    local: Vec<f64>,
    global: Vec<f64>,
    points: Vec<Vector3<f64>>,
}

/// The damped normal equations of one linearisation and their buffers: the reduced camera
/// system (the points eliminated) or the reduced point system (the cameras eliminated,
/// [`CameraElimination`]), whichever [`Elimination`] asks for.
enum LinearSystem {
    Points {
        vinv: Vec<Matrix3<f64>>,
        s: Vec<f64>,
        stack: MemBuffer,
    },
    Cameras(Box<CameraElimination>),
}

impl LinearSystem {
    fn new(elimination: Elimination, dims: Dims, inc: &Incidence, n_pts: usize) -> Self {
        let cameras = match elimination {
            Elimination::Auto => prefers_cameras(dims, inc, n_pts),
            Elimination::Points => false,
            Elimination::Cameras => true,
        };
        if cameras {
            LinearSystem::Cameras(Box::new(CameraElimination::new(dims, inc, n_pts)))
        } else {
            LinearSystem::Points {
                vinv: vec![Matrix3::zeros(); n_pts],
                s: vec![0.0; dims.n_r * dims.n_r],
                stack: cholesky_scratch(dims.n_r),
            }
        }
    }

    /// One damped step: the shared intrinsics' and cameras' part into `sol`, the points' into
    /// `dp`; `false` when the damped system is not positive definite.
    #[allow(clippy::too_many_arguments)]
    fn solve(
        &mut self,
        dims: Dims,
        inc: &Incidence,
        nrm: &Normal,
        lambda: f64,
        pinned: &[usize],
        sol: &mut [f64],
        dp: &mut [Vector3<f64>],
    ) -> bool {
        match self {
            LinearSystem::Points { vinv, s, stack } => {
                let solved = assemble_reduced(dims, inc, nrm, lambda, pinned, vinv, s, sol)
                    && cholesky_solve(s, dims.n_r, sol, stack);
                if solved {
                    back_substitute(dims, inc, nrm, vinv, sol, dp);
                }
                solved
            }
            LinearSystem::Cameras(e) => e.solve(dims, inc, nrm, lambda, pinned, sol, dp),
        }
    }
}

/// ½·Σ ρ(w·|r|²) over the observations, in fixed-order chunks; `None` if an observation that
/// counts (positive weight, `active`) cannot be projected.
fn total_cost<M: CameraModel>(p: &Problem<M>, active: &[bool], l: Loss) -> Option<f64> {
    let parts: Vec<Option<f64>> = p
        .observations
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(k, chunk)| {
            let mut sum = 0.0;
            for (i, o) in chunk.iter().enumerate() {
                if o.weight == 0.0 || !active[k * CHUNK + i] {
                    continue;
                }
                let r = p.residual(o)?;
                sum += loss(l, o.weight * r.norm_squared()).0;
            }
            Some(sum)
        })
        .collect();
    let mut total = 0.0;
    for part in parts {
        total += part?;
    }
    Some(0.5 * total)
}

/// Adjusts `problem` in place by Levenberg–Marquardt.
///
/// Observations whose projection is undefined at the start (behind the camera, outside the
/// distortion's valid region) are left out and counted in the summary.
///
/// # Errors
/// An invalid problem or configuration. A solve that stops without converging is not an error:
/// see [`AdjustSummary::termination`].
pub fn bundle_adjust<M: CameraModel>(
    problem: &mut Problem<M>,
    config: &AdjustConfig,
) -> Result<AdjustSummary, AdjustError> {
    config.validate()?;
    problem.validate()?;
    let dims = Dims::of(problem);
    if dims.dc > 32 || dims.dg > 32 {
        return Err(AdjustError::Invalid(
            "at most 32 shared and 26 per-camera intrinsics are supported".into(),
        ));
    }
    let inc = Incidence::new(problem);
    let n_obs = problem.observations.len();
    let n_pts = problem.points.len();
    let pinned = pinned_indices(problem, dims);
    let mut jac = vec![0.0; n_obs * dims.stride];
    let mut nrm = Normal::new(dims, n_pts, inc.num_pairs());
    let mut dp = vec![Vector3::zeros(); n_pts];
    let mut rhs = vec![0.0; dims.n_r];
    let mut linear = LinearSystem::new(config.elimination, dims, &inc, n_pts);

    // Observations that can be projected at the start.
    let active: Vec<bool> = problem
        .observations
        .par_iter()
        .map(|o| problem.residual(o).is_some())
        .collect();
    let dropped = active
        .iter()
        .zip(&problem.observations)
        .filter(|(a, o)| !**a && o.weight > 0.0)
        .count();
    let Some(initial_cost) = total_cost(problem, &active, config.loss) else {
        return Err(AdjustError::Invalid("cost undefined at the start".into()));
    };
    let mut cost = initial_cost;
    let mut radius = config.initial_trust_radius;
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut successful = 0;
    let mut termination = Termination::MaxIterations;
    let mut relinearise = true;
    let mut max_gradient = f64::INFINITY;
    let mut backup = State {
        poses: problem.cam_from_world.clone(),
        local: problem.local.clone(),
        global: problem.global.clone(),
        points: problem.points.clone(),
    };

    while iterations < config.max_iterations {
        if relinearise {
            let p: &Problem<M> = problem;
            jac.par_chunks_mut(dims.stride)
                .enumerate()
                .for_each(|(o, rec)| {
                    if active[o] {
                        linearise(p, dims, o, config.loss, rec);
                    } else {
                        rec.fill(0.0);
                    }
                });
            nrm.build(dims, &inc, &jac);
            max_gradient = gradient_max_norm(&nrm, &pinned, dims);
            if max_gradient <= config.gradient_tolerance {
                termination = Termination::Converged;
                break;
            }
            relinearise = false;
        }
        iterations += 1;
        let lambda = 1.0 / radius;
        let solved = linear.solve(dims, &inc, &nrm, lambda, &pinned, &mut rhs, &mut dp);
        let accepted = solved.then_some(()).and_then(|()| {
            let predicted = predicted_decrease(dims, problem, &active, &jac, &rhs, &dp);
            if predicted.is_nan() || predicted <= 0.0 {
                return None;
            }
            let step_norm = step_norm(&rhs, &dp);
            let x_norm = state_norm(problem);
            if step_norm <= config.parameter_tolerance * (x_norm + config.parameter_tolerance) {
                termination = Termination::Converged;
                return Some((0.0, predicted, true));
            }
            save_state(problem, &mut backup);
            apply_step(problem, dims, &pinned, &rhs, &dp);
            match total_cost(problem, &active, config.loss) {
                Some(new_cost) if new_cost.is_finite() => {
                    let rho = (cost - new_cost) / predicted;
                    if rho > MIN_RELATIVE_DECREASE {
                        Some((new_cost, rho, false))
                    } else {
                        restore_state(problem, &backup);
                        None
                    }
                }
                _ => {
                    restore_state(problem, &backup);
                    None
                }
            }
        });
        match accepted {
            Some((_, _, true)) => break,
            Some((new_cost, rho, false)) => {
                successful += 1;
                let change = cost - new_cost;
                cost = new_cost;
                radius =
                    (radius / (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3))).min(MAX_RADIUS);
                nu = 2.0;
                relinearise = true;
                if change <= config.function_tolerance * cost.max(f64::MIN_POSITIVE) {
                    termination = Termination::Converged;
                    break;
                }
            }
            None => {
                radius /= nu;
                nu *= 2.0;
                if radius < MIN_RADIUS {
                    termination = Termination::NoProgress;
                    break;
                }
            }
        }
    }
    let used = active
        .iter()
        .zip(&problem.observations)
        .filter(|(a, o)| **a && o.weight > 0.0)
        .count();
    Ok(AdjustSummary {
        initial_cost,
        final_cost: cost,
        iterations,
        successful_steps: successful,
        termination,
        observations_used: used,
        observations_dropped: dropped,
        max_gradient,
    })
}

fn gradient_max_norm(nrm: &Normal, pinned: &[usize], dims: Dims) -> f64 {
    let mut m: f64 = 0.0;
    let reduced = nrm.bg.iter().chain(nrm.bc.iter()).enumerate();
    for (k, v) in reduced {
        if k < dims.n_r && pinned.binary_search(&k).is_err() {
            m = m.max(v.abs());
        }
    }
    for b in &nrm.bp {
        m = m.max(b.amax());
    }
    m
}

/// `δp = (V + λD)⁻¹ (−b_p − Wᵀ δc)` for every point.
fn back_substitute(
    dims: Dims,
    inc: &Incidence,
    nrm: &Normal,
    vinv: &[Matrix3<f64>],
    dc_sol: &[f64],
    dp: &mut [Vector3<f64>],
) {
    let Dims { dg, dc, .. } = dims;
    dp.par_iter_mut().enumerate().for_each(|(p, d)| {
        let mut r = -nrm.bp[p];
        let wg = &nrm.wg[p * dg * 3..(p + 1) * dg * 3];
        for a in 0..dg {
            for k in 0..3 {
                r[k] -= wg[a * 3 + k] * dc_sol[a];
            }
        }
        for &pair in inc.pairs_of_point(p) {
            let wo = &nrm.wo[pair * dc * 3..(pair + 1) * dc * 3];
            let camera = inc.pair_camera[pair];
            let x = &dc_sol[dg + camera * dc..dg + (camera + 1) * dc];
            for a in 0..dc {
                for k in 0..3 {
                    r[k] -= wo[a * 3 + k] * x[a];
                }
            }
        }
        *d = vinv[p] * r;
    });
}

/// `½|r|² − ½|r + Jδ|²` of the linearised (IRLS-weighted) model.
fn predicted_decrease<M: CameraModel>(
    dims: Dims,
    problem: &Problem<M>,
    active: &[bool],
    jac: &[f64],
    sol: &[f64],
    dp: &[Vector3<f64>],
) -> f64 {
    let Dims { dg, dc, stride, .. } = dims;
    let parts: Vec<f64> = jac
        .par_chunks(stride * CHUNK)
        .enumerate()
        .map(|(k, chunk)| {
            let mut sum = 0.0;
            for (i, rec) in chunk.chunks(stride).enumerate() {
                let o = k * CHUNK + i;
                if !active[o] {
                    continue;
                }
                let obs = &problem.observations[o];
                let rec = view(rec, dims);
                let x = &sol[dg + obs.camera * dc..dg + (obs.camera + 1) * dc];
                let d = &dp[obs.point];
                for row in 0..2 {
                    let mut jd = 0.0;
                    for c in 0..3 {
                        jd += rec.jp[row * 3 + c] * d[c];
                    }
                    jd += dot(&rec.jc[row * dc..(row + 1) * dc], x);
                    jd += dot(&rec.jg[row * dg..(row + 1) * dg], &sol[..dg]);
                    let r = rec.r[row];
                    sum += 0.5 * (r * r - (r + jd) * (r + jd));
                }
            }
            sum
        })
        .collect();
    parts.iter().sum()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn step_norm(sol: &[f64], dp: &[Vector3<f64>]) -> f64 {
    (sol.iter().map(|v| v * v).sum::<f64>() + dp.iter().map(|d| d.norm_squared()).sum::<f64>())
        .sqrt()
}

fn state_norm<M: CameraModel>(p: &Problem<M>) -> f64 {
    let poses: f64 = p
        .cam_from_world
        .iter()
        .map(|c| c.translation.vector.norm_squared() + c.rotation.scaled_axis().norm_squared())
        .sum();
    let pts: f64 = p.points.iter().map(|x| x.norm_squared()).sum();
    let intr: f64 = p.local.iter().chain(&p.global).map(|v| v * v).sum();
    (poses + pts + intr).sqrt()
}

fn save_state<M: CameraModel>(p: &Problem<M>, s: &mut State) {
    s.poses.clone_from(&p.cam_from_world);
    s.local.clone_from(&p.local);
    s.global.clone_from(&p.global);
    s.points.clone_from(&p.points);
}

fn restore_state<M: CameraModel>(p: &mut Problem<M>, s: &State) {
    p.cam_from_world.clone_from(&s.poses);
    p.local.clone_from(&s.local);
    p.global.clone_from(&s.global);
    p.points.clone_from(&s.points);
}

fn apply_step<M: CameraModel>(
    p: &mut Problem<M>,
    dims: Dims,
    pinned: &[usize],
    sol: &[f64],
    dp: &[Vector3<f64>],
) {
    let Dims { dg, dc, nl, .. } = dims;
    for (g, v) in p.global.iter_mut().enumerate() {
        if pinned.binary_search(&g).is_err() {
            *v += sol[g];
        }
    }
    for (c, pose) in p.cam_from_world.iter_mut().enumerate() {
        let x = &sol[dg + c * dc..dg + (c + 1) * dc];
        *pose = retract(pose, &Vector6::from_column_slice(&x[..6]));
        for k in 0..nl {
            p.local[c * nl + k] += x[6 + k];
        }
    }
    p.points
        .par_iter_mut()
        .zip(dp.par_iter())
        .for_each(|(x, d)| *x += d);
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A random symmetric positive definite n×n matrix (column-major) and right-hand side.
    fn spd(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let b: Vec<f64> = (0..n * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..=i {
                let v: f64 = (0..n).map(|k| b[i * n + k] * b[j * n + k]).sum();
                a[i * n + j] = v;
                a[j * n + i] = v;
            }
            a[i * n + i] += n as f64;
        }
        let rhs = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        (a, rhs)
    }

    fn solve_on(threads: usize, a: &[f64], rhs: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let n = rhs.len();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let (mut s, mut x) = (a.to_vec(), rhs.to_vec());
            let mut stack = cholesky_scratch(n);
            assert!(cholesky_solve(&mut s, n, &mut x, &mut stack));
            (s, x)
        })
    }

    #[test]
    fn cholesky_is_the_same_on_any_thread_count() {
        // Sizes about and above faer's blocking thresholds, up to a 90-frame fourth-order
        // reduced system.
        for (n, seed) in [(97, 1), (640, 2), (2710, 3)] {
            let (a, rhs) = spd(n, seed);
            let (s1, x1) = solve_on(1, &a, &rhs);
            // The solution solves the system (residual against the original matrix).
            let worst = (0..n)
                .map(|i| {
                    let ax: f64 = (0..n).map(|j| a[i * n + j] * x1[j]).sum();
                    (ax - rhs[i]).abs()
                })
                .fold(0.0, f64::max);
            assert!(worst < 1e-9, "n {n}: residual {worst}");
            for threads in [2, 3] {
                let (s, x) = solve_on(threads, &a, &rhs);
                assert!(x == x1, "n {n}: solution differs on {threads} threads");
                assert!(s == s1, "n {n}: factor differs on {threads} threads");
            }
        }
    }
}
