//! The reduced *point* system: Levenberg–Marquardt's damped normal equations with the cameras
//! eliminated instead of the points (Triggs et al. 2000, §6.1: either set may be eliminated;
//! docs/math.md "Schur"), for networks with more camera unknowns than point unknowns. A
//! calibration video is one: 90 frames with third-order rolling-shutter motions carry
//! 90 × 24 = 2,160 camera unknowns against 109 targets × 3, so the reduced camera system is a
//! 2,170² Cholesky (3.4 GFLOP a step) where this one is 338².
//!
//! ```text
//! [A   B] [x]     [b_x]     x: each camera's block (pose, per-camera values)
//! [Bᵀ  C] [y] = − [b_y]     y: the shared intrinsics, then every point
//!
//! (C − Σ_c B_cᵀ A_c⁻¹ B_c) y = −b_y + Σ_c B_cᵀ A_c⁻¹ b_c,    x_c = −A_c⁻¹ (b_c + B_c y)
//! ```
//!
//! `A` is block diagonal (one damped `U_c`, dc×dc, per camera), so its inverse is one small
//! Cholesky factor per camera; `C` holds the shared intrinsics' block, their coupling to the
//! points and the points' 3×3 blocks; `B_c` is camera c's coupling to the shared intrinsics and
//! to the points it sees. The system and its damping are those of the reduced camera system
//! ([`super::solver`]), so both give the same step to rounding; [`prefers_cameras`] picks the
//! cheaper by counting their floating-point operations.
//!
//! Every sum runs in a fixed order (cameras in order, a point's cameras in order), so the step
//! does not depend on the thread count.

use faer::dyn_stack::MemBuffer;
use nalgebra::Vector3;
use rayon::prelude::*;

use super::normal::{Dims, Incidence, Normal, cholesky_scratch, cholesky_solve, damped};
use super::problem::MAX_LOCAL;

/// Largest camera block: a pose and [`MAX_LOCAL`] per-camera values.
const MAX_DC: usize = 6 + MAX_LOCAL;

/// Floating-point operations of one damped step by the reduced camera system (the point
/// elimination of [`super::solver`]): each pair of cameras seeing a point adds a dc×dc block
/// (`6·dc²`), then the Cholesky of `n_r²`.
fn points_cost(dims: Dims, inc: &Incidence, n_pts: usize) -> f64 {
    let dc = dims.dc as f64;
    let pairs: f64 = (0..n_pts)
        .map(|p| {
            let m = inc.pairs_of_point(p).len() as f64;
            m * (m + 1.0) / 2.0
        })
        .sum();
    let n = dims.n_r as f64;
    pairs * 6.0 * dc * dc + n * n * n / 3.0
}

/// Floating-point operations of one damped step by the reduced point system: each camera's
/// `A_c⁻¹ B_c` (`2·dc²·k_c`), each pair's row of `B_cᵀ A_c⁻¹ B_c` up to the diagonal, then the
/// Cholesky of `m²`.
fn cameras_cost(dims: Dims, inc: &Incidence, n_pts: usize) -> f64 {
    let (dc, dg) = (dims.dc as f64, dims.dg as f64);
    let per_camera: f64 = (0..dims.n_cam)
        .map(|c| {
            let n = inc.pairs_of_camera(c).len() as f64;
            let k = dg + 3.0 * n;
            2.0 * dc * dc * k + 6.0 * dc * (n * dg + 1.5 * n * (n + 1.0))
        })
        .sum();
    let m = (dims.dg + 3 * n_pts) as f64;
    per_camera + m * m * m / 3.0
}

/// Whether eliminating the cameras costs fewer operations than eliminating the points.
pub(crate) fn prefers_cameras(dims: Dims, inc: &Incidence, n_pts: usize) -> bool {
    dims.dc <= MAX_DC && cameras_cost(dims, inc, n_pts) < points_cost(dims, inc, n_pts)
}

/// The reduced point system's buffers, allocated once per adjustment.
pub(crate) struct CameraElimination {
    /// Per camera: `k_c`, the shared intrinsics and 3 per point it sees (the columns of `B_c`).
    k: Vec<usize>,
    /// Stride of one camera's block in `y`: dc × the largest `k_c`.
    y_stride: usize,
    /// Per camera: `A_c⁻¹ B_c` (dc × k_c, row-major).
    y: Vec<f64>,
    /// Per camera: `A_c⁻¹ b_c` (dc).
    z: Vec<f64>,
    /// Each pair's position among its camera's pairs (its columns in `B_c`).
    pair_pos: Vec<usize>,
    /// The reduced system (m×m, row-major; m = dg + 3·points) and its right-hand side.
    s: Vec<f64>,
    rhs: Vec<f64>,
    stack: MemBuffer,
}

impl CameraElimination {
    pub(crate) fn new(dims: Dims, inc: &Incidence, n_pts: usize) -> Self {
        let Dims { dg, dc, n_cam, .. } = dims;
        let k: Vec<usize> = (0..n_cam)
            .map(|c| dg + 3 * inc.pairs_of_camera(c).len())
            .collect();
        let k_max = k.iter().copied().max().unwrap_or(0).max(1);
        let mut pair_pos = vec![0; inc.num_pairs()];
        for c in 0..n_cam {
            for (t, &pair) in inc.pairs_of_camera(c).iter().enumerate() {
                pair_pos[pair] = t;
            }
        }
        let m = dg + 3 * n_pts;
        CameraElimination {
            k,
            y_stride: dc * k_max,
            y: vec![0.0; n_cam * dc * k_max],
            z: vec![0.0; n_cam * dc],
            pair_pos,
            s: vec![0.0; m * m],
            rhs: vec![0.0; m],
            stack: cholesky_scratch(m),
        }
    }

    /// One damped step: the cameras' and shared intrinsics' part into `sol` (the layout of the
    /// reduced camera system: shared intrinsics, then dc per camera) and the points' into `dp`.
    /// `false` when a camera block or the reduced system is not positive definite.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn solve(
        &mut self,
        dims: Dims,
        inc: &Incidence,
        nrm: &Normal,
        lambda: f64,
        pinned: &[usize],
        sol: &mut [f64],
        dp: &mut [Vector3<f64>],
    ) -> bool {
        let Dims { dg, dc, .. } = dims;
        let m = self.rhs.len();
        let mut pinned_global = [false; 32];
        for &g in pinned.iter().take_while(|&&g| g < dg) {
            pinned_global[g] = true;
        }
        // A_c⁻¹ B_c and A_c⁻¹ b_c, camera by camera.
        let k = &self.k;
        let ok = self
            .y
            .par_chunks_mut(self.y_stride)
            .zip(self.z.par_chunks_mut(dc))
            .enumerate()
            .all(|(c, (y, z))| {
                let y = &mut y[..dc * k[c]];
                camera_block(dims, inc, nrm, lambda, pinned, &pinned_global, c, y, z)
            });
        if !ok {
            return false;
        }
        self.assemble(dims, inc, nrm, lambda);
        let k = &self.k;
        for (g, &fixed) in pinned_global[..dg].iter().enumerate() {
            if fixed {
                for j in 0..m {
                    self.s[g * m + j] = 0.0;
                    self.s[j * m + g] = 0.0;
                }
                self.s[g * m + g] = 1.0;
                self.rhs[g] = 0.0;
            }
        }
        if !cholesky_solve(&mut self.s, m, &mut self.rhs, &mut self.stack) {
            return false;
        }
        // Back substitution: x_c = −(z_c + Y_c·y_c).
        let y_sol = &self.rhs;
        sol[..dg].copy_from_slice(&y_sol[..dg]);
        for (p, d) in dp.iter_mut().enumerate() {
            *d = Vector3::from_column_slice(&y_sol[dg + 3 * p..dg + 3 * p + 3]);
        }
        let (ys, zs, stride) = (&self.y, &self.z, self.y_stride);
        sol[dg..].par_chunks_mut(dc).enumerate().for_each(|(c, x)| {
            let kc = k[c];
            let y = &ys[c * stride..c * stride + dc * kc];
            let pairs = inc.pairs_of_camera(c);
            for (i, xi) in x.iter_mut().enumerate() {
                let row = &y[i * kc..(i + 1) * kc];
                let mut v = zs[c * dc + i];
                for g in 0..dg {
                    v += row[g] * y_sol[g];
                }
                for (t, &pair) in pairs.iter().enumerate() {
                    let col = dg + 3 * inc.pair_point[pair];
                    for e in 0..3 {
                        v += row[dg + 3 * t + e] * y_sol[col + e];
                    }
                }
                *xi = -v;
            }
        });
        true
    }

    /// The lower triangle of `C − Σ_c B_cᵀ Y_c` and `−b_y + Σ_c B_cᵀ z_c`, mirrored: the shared
    /// intrinsics' rows, then each point's three rows in parallel.
    fn assemble(&mut self, dims: Dims, inc: &Incidence, nrm: &Normal, lambda: f64) {
        let Dims { dg, dc, n_cam, .. } = dims;
        let m = self.rhs.len();
        let (k, ys, zs, stride, pair_pos) =
            (&self.k, &self.y, &self.z, self.y_stride, &self.pair_pos);
        let (s_g, s_p) = self.s.split_at_mut(dg * m);
        let (rhs_g, rhs_p) = self.rhs.split_at_mut(dg);
        for a in 0..dg {
            let row = &mut s_g[a * m..a * m + dg];
            row.copy_from_slice(&nrm.ug[a * dg..(a + 1) * dg]);
            row[a] += damped(lambda, nrm.ug[a * dg + a]);
            rhs_g[a] = -nrm.bg[a];
            for c in 0..n_cam {
                let ugc = &nrm.ugc[c * dg * dc + a * dc..c * dg * dc + (a + 1) * dc];
                let y = &ys[c * stride..];
                for (i, &u) in ugc.iter().enumerate() {
                    for (v, yv) in row.iter_mut().zip(&y[i * k[c]..i * k[c] + dg]) {
                        *v -= u * yv;
                    }
                    rhs_g[a] += u * zs[c * dc + i];
                }
            }
        }
        s_p.par_chunks_mut(3 * m)
            .zip(rhs_p.par_chunks_mut(3))
            .enumerate()
            .for_each_init(
                || vec![0.0; 3 * m],
                |tmp, (p, (rows, rhs))| {
                    let diag = dg + 3 * p;
                    let v = &nrm.v[p];
                    let wg = &nrm.wg[p * dg * 3..(p + 1) * dg * 3];
                    for e in 0..3 {
                        let row = &mut rows[e * m..e * m + diag + 3];
                        row.fill(0.0);
                        for g in 0..dg {
                            row[g] = wg[g * 3 + e];
                        }
                        for f in 0..3 {
                            row[diag + f] = v[(e, f)];
                        }
                        row[diag + e] += damped(lambda, v[(e, e)]);
                        rhs[e] = -nrm.bp[p][e];
                    }
                    for &pair in inc.pairs_of_point(p) {
                        let c = inc.pair_camera[pair];
                        let (kc, t) = (k[c], pair_pos[pair]);
                        let len = dg + 3 * (t + 1);
                        let y = &ys[c * stride..c * stride + dc * kc];
                        let z = &zs[c * dc..(c + 1) * dc];
                        let w = &nrm.wo[pair * dc * 3..(pair + 1) * dc * 3];
                        // tmp[e] = (W_pairᵀ Y_c)[e, ..len]: this camera's columns up to the
                        // diagonal.
                        for e in 0..3 {
                            tmp[e * m..e * m + len].fill(0.0);
                        }
                        for i in 0..dc {
                            let yi = &y[i * kc..i * kc + len];
                            for e in 0..3 {
                                let wie = w[i * 3 + e];
                                if wie != 0.0 {
                                    for (a, b) in tmp[e * m..e * m + len].iter_mut().zip(yi) {
                                        *a += wie * b;
                                    }
                                }
                                rhs[e] += wie * z[i];
                            }
                        }
                        let pairs = &inc.pairs_of_camera(c)[..=t];
                        for e in 0..3 {
                            let row = &mut rows[e * m..(e + 1) * m];
                            let t_row = &tmp[e * m..e * m + len];
                            for g in 0..dg {
                                row[g] -= t_row[g];
                            }
                            for (t2, &pair2) in pairs.iter().enumerate() {
                                let col = dg + 3 * inc.pair_point[pair2];
                                for f in 0..3 {
                                    row[col + f] -= t_row[dg + 3 * t2 + f];
                                }
                            }
                        }
                    }
                },
            );
        mirror_lower(&mut self.s, m);
    }
}

/// `A_c⁻¹ B_c` into `y` (dc × k_c) and `A_c⁻¹ b_c` into `z` for camera `c`, with its pinned
/// values' rows and columns of `A_c` replaced by the identity's and their rows of `B_c` and
/// `b_c` (and the pinned shared intrinsics' columns of `B_c`) zero, so their steps are zero.
/// `false` when the damped block is not positive definite.
#[allow(clippy::too_many_arguments)]
fn camera_block(
    dims: Dims,
    inc: &Incidence,
    nrm: &Normal,
    lambda: f64,
    pinned: &[usize],
    pinned_global: &[bool; 32],
    c: usize,
    y: &mut [f64],
    z: &mut [f64],
) -> bool {
    let Dims { dg, dc, .. } = dims;
    let kc = y.len() / dc;
    let base = dg + c * dc;
    let mut fixed = [false; MAX_DC];
    let from = pinned.partition_point(|&i| i < base);
    for &i in pinned[from..].iter().take_while(|&&i| i < base + dc) {
        fixed[i - base] = true;
    }
    let u = &nrm.u[c * dc * dc..(c + 1) * dc * dc];
    let mut a = [0.0; MAX_DC * MAX_DC];
    let a = &mut a[..dc * dc];
    a.copy_from_slice(u);
    for i in 0..dc {
        a[i * dc + i] += damped(lambda, u[i * dc + i]);
    }
    let ugc = &nrm.ugc[c * dg * dc..(c + 1) * dg * dc];
    let pairs = inc.pairs_of_camera(c);
    for i in 0..dc {
        let row = &mut y[i * kc..(i + 1) * kc];
        if fixed[i] {
            row.fill(0.0);
            z[i] = 0.0;
            for j in 0..dc {
                a[i * dc + j] = 0.0;
                a[j * dc + i] = 0.0;
            }
            a[i * dc + i] = 1.0;
            continue;
        }
        for g in 0..dg {
            row[g] = if pinned_global[g] {
                0.0
            } else {
                ugc[g * dc + i]
            };
        }
        for (t, &pair) in pairs.iter().enumerate() {
            let w = &nrm.wo[pair * dc * 3 + i * 3..pair * dc * 3 + i * 3 + 3];
            row[dg + 3 * t..dg + 3 * t + 3].copy_from_slice(w);
        }
        z[i] = nrm.bc[c * dc + i];
    }
    if !cholesky_small(a, dc) {
        return false;
    }
    solve_small(a, dc, y, kc);
    solve_small(a, dc, z, 1);
    true
}

/// In-place Cholesky `A = L·Lᵀ` of a row-major n×n symmetric positive definite matrix (`L` in
/// the lower triangle); `false` if it is not positive definite.
fn cholesky_small(a: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut v = a[i * n + j];
            for k in 0..j {
                v -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = v / d;
        }
    }
    true
}

/// Solves `L·Lᵀ·X = B` in place for row-major `B` (n × k), `L` from [`cholesky_small`]: row
/// operations, so the inner loops run along `B`'s rows.
fn solve_small(l: &[f64], n: usize, b: &mut [f64], k: usize) {
    for i in 0..n {
        let (done, rest) = b.split_at_mut(i * k);
        let row = &mut rest[..k];
        for j in 0..i {
            let lij = l[i * n + j];
            if lij != 0.0 {
                for (v, d) in row.iter_mut().zip(&done[j * k..(j + 1) * k]) {
                    *v -= lij * d;
                }
            }
        }
        let inv = 1.0 / l[i * n + i];
        row.iter_mut().for_each(|v| *v *= inv);
    }
    for i in (0..n).rev() {
        let (head, done) = b.split_at_mut((i + 1) * k);
        let row = &mut head[i * k..];
        for j in i + 1..n {
            let lji = l[j * n + i];
            if lji != 0.0 {
                let d = &done[(j - i - 1) * k..(j - i) * k];
                for (v, dv) in row.iter_mut().zip(d) {
                    *v -= lji * dv;
                }
            }
        }
        let inv = 1.0 / l[i * n + i];
        row.iter_mut().for_each(|v| *v *= inv);
    }
}

/// Copies the lower triangle of a row-major n×n matrix onto its upper triangle.
fn mirror_lower(s: &mut [f64], n: usize) {
    for i in 1..n {
        let (upper, rest) = s.split_at_mut(i * n);
        for (j, v) in rest[..i].iter().enumerate() {
            upper[j * n + i] = *v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn small_cholesky_solves_many_right_hand_sides() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let n = 24;
        let g: Vec<f64> = (0..n * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|q| g[i * n + q] * g[j * n + q]).sum();
            }
            a[i * n + i] += 1.0;
        }
        let k = 7;
        let b: Vec<f64> = (0..n * k).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut l = a.clone();
        assert!(cholesky_small(&mut l, n));
        let mut x = b.clone();
        solve_small(&l, n, &mut x, k);
        for i in 0..n {
            for col in 0..k {
                let ax: f64 = (0..n).map(|j| a[i * n + j] * x[j * k + col]).sum();
                assert!((ax - b[i * k + col]).abs() < 1e-10, "({i}, {col}): {ax}");
            }
        }
        let mut not_pd = a.clone();
        not_pd[5 * n + 5] = -1.0;
        assert!(!cholesky_small(&mut not_pd, n));
    }
}
