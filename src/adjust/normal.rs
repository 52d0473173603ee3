//! The normal equations of one linearisation of the bundle adjustment (Triggs et al. 2000,
//! §6.1; docs/math.md "Schur"): which observations each point and camera has
//! ([`Incidence`]), the layout of the camera block ([`Dims`]), the robustified Jacobians
//! ([`linearise`]), the blocks `U`, `W`, `V` and the right-hand side ([`Normal`]), the reduced
//! camera system `S` with the points eliminated, and faer's dense Cholesky that solves it.
//! [`super::solver`] drives the Levenberg–Marquardt iterations over them;
//! [`super::elimination`] eliminates the cameras instead when that costs fewer operations.
//!
//! Every sum is taken in a fixed order over chunks of observations, so the result does not
//! depend on the thread count.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::{MatMut, Par};
use nalgebra::{Matrix2x3, Matrix3, Vector3};
use rayon::prelude::*;

use super::Loss;
use super::model::{CameraModel, ModelJacobians};
use super::problem::{MAX_LOCAL, Problem};
use crate::geometry::pose::skew;

/// Observations per chunk of the fixed-order parallel sums.
pub(super) const CHUNK: usize = 512;
/// Ceres' `min_lm_diagonal` and `max_lm_diagonal`.
const MIN_DIAGONAL: f64 = 1e-6;

const MAX_DIAGONAL: f64 = 1e32;

/// Compressed lists of observation indices per point and per camera.
#[derive(Debug, Clone)]
pub(crate) struct Incidence {
    pub(crate) by_point: Vec<usize>,
    pub(crate) point_start: Vec<usize>,
    pub(crate) by_camera: Vec<usize>,
    pub(crate) camera_start: Vec<usize>,
    /// The (camera, point) pairs, ordered by camera then point: the observations of one point
    /// by one camera (a video frame's neighbours observe it again at other times) share one
    /// `W` block, so the Schur complement's cost grows with the pairs, not the observations.
    /// The observations of pair k are `pair_obs[pair_start[k]..pair_start[k + 1]]`.
    pub(crate) pair_obs: Vec<usize>,
    pub(crate) pair_start: Vec<usize>,
    /// The camera and the point of each pair.
    pub(crate) pair_camera: Vec<usize>,
    pub(crate) pair_point: Vec<usize>,
    /// Pair indices grouped by camera and by point.
    pub(crate) pairs_by_camera: Vec<usize>,
    pub(crate) camera_pair_start: Vec<usize>,
    pub(crate) pairs_by_point: Vec<usize>,
    pub(crate) point_pair_start: Vec<usize>,
}

impl Incidence {
    pub(crate) fn new<M: CameraModel>(p: &Problem<M>) -> Self {
        let (by_point, point_start) = group(p.observations.iter().map(|o| o.point), p.points.len());
        let (by_camera, camera_start) =
            group(p.observations.iter().map(|o| o.camera), p.num_cameras());
        let key = |o: usize| (p.observations[o].camera, p.observations[o].point);
        let mut pair_obs: Vec<usize> = (0..p.observations.len()).collect();
        pair_obs.sort_by_key(|&o| (key(o), o));
        let (mut pair_start, mut pair_camera, mut pair_point) =
            (Vec::new(), Vec::new(), Vec::new());
        for (i, &o) in pair_obs.iter().enumerate() {
            if i == 0 || key(o) != key(pair_obs[i - 1]) {
                pair_start.push(i);
                pair_camera.push(key(o).0);
                pair_point.push(key(o).1);
            }
        }
        pair_start.push(pair_obs.len());
        let (pairs_by_camera, camera_pair_start) =
            group(pair_camera.iter().copied(), p.num_cameras());
        let (pairs_by_point, point_pair_start) = group(pair_point.iter().copied(), p.points.len());
        Incidence {
            by_point,
            point_start,
            by_camera,
            camera_start,
            pair_obs,
            pair_start,
            pair_camera,
            pair_point,
            pairs_by_camera,
            camera_pair_start,
            pairs_by_point,
            point_pair_start,
        }
    }

    /// The number of (camera, point) pairs.
    pub(crate) fn num_pairs(&self) -> usize {
        self.pair_camera.len()
    }

    /// The observations of pair `k`.
    pub(crate) fn obs_of_pair(&self, k: usize) -> &[usize] {
        &self.pair_obs[self.pair_start[k]..self.pair_start[k + 1]]
    }

    /// The pairs of camera `c`.
    pub(crate) fn pairs_of_camera(&self, c: usize) -> &[usize] {
        &self.pairs_by_camera[self.camera_pair_start[c]..self.camera_pair_start[c + 1]]
    }

    /// The pairs of point `p`.
    pub(crate) fn pairs_of_point(&self, p: usize) -> &[usize] {
        &self.pairs_by_point[self.point_pair_start[p]..self.point_pair_start[p + 1]]
    }

    pub(crate) fn of_point(&self, p: usize) -> &[usize] {
        &self.by_point[self.point_start[p]..self.point_start[p + 1]]
    }

    pub(crate) fn of_camera(&self, c: usize) -> &[usize] {
        &self.by_camera[self.camera_start[c]..self.camera_start[c + 1]]
    }
}

/// Counting sort of observation indices by key.
fn group(keys: impl Iterator<Item = usize> + Clone, n: usize) -> (Vec<usize>, Vec<usize>) {
    let mut start = vec![0usize; n + 1];
    for k in keys.clone() {
        start[k + 1] += 1;
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut next = start.clone();
    let mut out = vec![0usize; start[n]];
    for (o, k) in keys.enumerate() {
        out[next[k]] = o;
        next[k] += 1;
    }
    (out, start)
}

/// Sizes of the blocks.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Dims {
    /// Shared intrinsics.
    pub(crate) dg: usize,
    /// Per-camera intrinsics.
    pub(crate) nl: usize,
    /// One camera block: 6 + nl.
    pub(crate) dc: usize,
    /// Cameras.
    pub(crate) n_cam: usize,
    /// Reduced system: dg + n_cam·dc.
    pub(crate) n_r: usize,
    /// Stride of one observation's record in the Jacobian buffer.
    pub(crate) stride: usize,
}

impl Dims {
    pub(crate) fn of<M: CameraModel>(p: &Problem<M>) -> Self {
        let dg = p.model.global_len();
        let nl = p.model.local_len();
        let dc = 6 + nl;
        let n_cam = p.num_cameras();
        Dims {
            dg,
            nl,
            dc,
            n_cam,
            n_r: dg + n_cam * dc,
            // r (2), jp (2×3), jc (2×dc), jg (2×dg)
            stride: 2 + 6 + 2 * dc + 2 * dg,
        }
    }
}

/// The value of the loss and its derivative at `s = w·|r|²`.
pub(super) fn loss(l: Loss, s: f64) -> (f64, f64) {
    match l {
        Loss::Squared => (s, 1.0),
        Loss::Huber(b) => {
            let b2 = b * b;
            if s <= b2 {
                (s, 1.0)
            } else {
                let rs = s.sqrt();
                (2.0 * b * rs - b2, b / rs)
            }
        }
        Loss::Cauchy(b) => {
            let b2 = b * b;
            (b2 * (s / b2).ln_1p(), 1.0 / (1.0 + s / b2))
        }
    }
}

/// Linearises one observation into `rec` (residual and Jacobians scaled by the square root of
/// the IRLS weight); returns `false` (record zeroed) where the model is undefined.
pub(crate) fn linearise<M: CameraModel>(
    p: &Problem<M>,
    dims: Dims,
    o: usize,
    loss_fn: Loss,
    rec: &mut [f64],
) -> bool {
    let obs = &p.observations[o];
    rec.fill(0.0);
    if obs.weight == 0.0 {
        return true;
    }
    let pose = &p.cam_from_world[obs.camera];
    let r_x = pose.rotation * p.points[obs.point];
    let p_cam = r_x + pose.translation.vector;
    let mut d_p_cam = Matrix2x3::zeros();
    let (head, tail) = rec.split_at_mut(8 + 2 * dims.dc);
    let mut d_local = [0.0; 2 * MAX_LOCAL];
    let d_local = &mut d_local[..2 * dims.nl];
    let Some(uv) = p.model.project(
        p.local_of(obs.camera),
        &p.global,
        &p_cam,
        obs.time_offset_s,
        Some(ModelJacobians {
            d_p_cam: &mut d_p_cam,
            d_local,
            d_global: tail,
        }),
    ) else {
        rec.fill(0.0);
        return false;
    };
    let r = uv - obs.uv;
    let (_, d_rho) = loss(loss_fn, obs.weight * r.norm_squared());
    let sw = (obs.weight * d_rho).sqrt();
    head[0] = sw * r.x;
    head[1] = sw * r.y;
    let rot = pose.rotation.to_rotation_matrix();
    let jp = d_p_cam * rot.matrix();
    let jw = -d_p_cam * skew(&r_x);
    for row in 0..2 {
        for c in 0..3 {
            head[2 + row * 3 + c] = sw * jp[(row, c)];
        }
        let jc = &mut head[8 + row * dims.dc..8 + (row + 1) * dims.dc];
        for c in 0..3 {
            jc[c] = sw * jw[(row, c)];
            jc[3 + c] = sw * d_p_cam[(row, c)];
        }
        for c in 0..dims.nl {
            jc[6 + c] = sw * d_local[row * dims.nl + c];
        }
    }
    for v in tail.iter_mut() {
        *v *= sw;
    }
    true
}

/// A view of one observation's record: residual (2), and row-major Jacobians w.r.t. the point
/// (2×3), its camera's block (2×dc) and the shared intrinsics (2×dg).
pub(crate) struct Rec<'a> {
    pub(crate) r: &'a [f64],
    pub(crate) jp: &'a [f64],
    pub(crate) jc: &'a [f64],
    pub(crate) jg: &'a [f64],
}

pub(crate) fn view(rec: &[f64], dims: Dims) -> Rec<'_> {
    let (r, rest) = rec.split_at(2);
    let (jp, rest) = rest.split_at(6);
    let (jc, jg) = rest.split_at(2 * dims.dc);
    Rec { r, jp, jc, jg }
}

/// `Aᵀ·B` of two row-major 2×m and 2×n blocks, accumulated into row-major m×n `out`.
fn add_at_b(a: &[f64], m: usize, b: &[f64], n: usize, out: &mut [f64]) {
    for i in 0..m {
        let (a0, a1) = (a[i], a[m + i]);
        if a0 == 0.0 && a1 == 0.0 {
            continue;
        }
        let row = &mut out[i * n..(i + 1) * n];
        for j in 0..n {
            row[j] += a0 * b[j] + a1 * b[n + j];
        }
    }
}

/// `Aᵀ·r` of a row-major 2×m block, accumulated.
fn add_at_r(a: &[f64], m: usize, r: &[f64], out: &mut [f64]) {
    for i in 0..m {
        out[i] += a[i] * r[0] + a[m + i] * r[1];
    }
}

/// Normal-equation blocks of one linearisation.
pub(crate) struct Normal {
    /// Per point: V (3×3).
    pub(crate) v: Vec<Matrix3<f64>>,
    /// Per point: b_p.
    pub(crate) bp: Vec<Vector3<f64>>,
    /// Per point: W_gp (dg×3), row-major.
    pub(crate) wg: Vec<f64>,
    /// Per (camera, point) pair ([`Incidence::pair_obs`]): `W = Σ jcᵀ jp` over its
    /// observations (dc×3), row-major.
    pub(crate) wo: Vec<f64>,
    /// Per camera: U_i (dc×dc).
    pub(crate) u: Vec<f64>,
    /// Per camera: U_gi (dg×dc).
    pub(crate) ugc: Vec<f64>,
    /// Per camera: b_i.
    pub(crate) bc: Vec<f64>,
    /// Shared: U_g (dg×dg) and b_g.
    pub(crate) ug: Vec<f64>,
    pub(crate) bg: Vec<f64>,
    /// Per camera: partial U_g and b_g (summed in camera order).
    ug_part: Vec<f64>,
    bg_part: Vec<f64>,
}

impl Normal {
    pub(super) fn new(dims: Dims, n_pts: usize, n_pairs: usize) -> Self {
        let Dims { dg, dc, n_cam, .. } = dims;
        Normal {
            v: vec![Matrix3::zeros(); n_pts],
            bp: vec![Vector3::zeros(); n_pts],
            // Blocks sized by dg get at least one slot each so the parallel zips below keep
            // one chunk per point or camera when there are no shared intrinsics.
            wg: vec![0.0; n_pts * (dg * 3).max(1)],
            wo: vec![0.0; n_pairs * dc * 3],
            u: vec![0.0; n_cam * dc * dc],
            ugc: vec![0.0; n_cam * (dg * dc).max(1)],
            bc: vec![0.0; n_cam * dc],
            ug: vec![0.0; dg * dg],
            bg: vec![0.0; dg],
            ug_part: vec![0.0; n_cam * (dg * dg).max(1)],
            bg_part: vec![0.0; n_cam * dg.max(1)],
        }
    }

    /// Builds every block from the Jacobian records.
    pub(super) fn build(&mut self, dims: Dims, inc: &Incidence, jac: &[f64]) {
        let Dims { dg, dc, stride, .. } = dims;
        self.v
            .par_iter_mut()
            .zip(self.bp.par_iter_mut())
            .zip(self.wg.par_chunks_mut((dg * 3).max(1)))
            .enumerate()
            .for_each(|(p, ((v, bp), wg))| {
                let mut vv = [0.0; 9];
                let mut b = [0.0; 3];
                wg.fill(0.0);
                for &o in inc.of_point(p) {
                    let rec = view(&jac[o * stride..(o + 1) * stride], dims);
                    add_at_b(rec.jp, 3, rec.jp, 3, &mut vv);
                    add_at_r(rec.jp, 3, rec.r, &mut b);
                    if dg > 0 {
                        add_at_b(rec.jg, dg, rec.jp, 3, wg);
                    }
                }
                *v = Matrix3::from_row_slice(&vv);
                *bp = Vector3::from_row_slice(&b);
            });
        self.wo
            .par_chunks_mut(dc * 3)
            .enumerate()
            .for_each(|(k, w)| {
                w.fill(0.0);
                for &o in inc.obs_of_pair(k) {
                    let rec = view(&jac[o * stride..(o + 1) * stride], dims);
                    add_at_b(rec.jc, dc, rec.jp, 3, w);
                }
            });
        self.u
            .par_chunks_mut(dc * dc)
            .zip(self.ugc.par_chunks_mut((dg * dc).max(1)))
            .zip(self.bc.par_chunks_mut(dc))
            .zip(self.ug_part.par_chunks_mut((dg * dg).max(1)))
            .zip(self.bg_part.par_chunks_mut(dg.max(1)))
            .enumerate()
            .for_each(|(c, ((((u, ugc), bc), ugp), bgp))| {
                u.fill(0.0);
                ugc.fill(0.0);
                bc.fill(0.0);
                ugp.fill(0.0);
                bgp.fill(0.0);
                for &o in inc.of_camera(c) {
                    let rec = view(&jac[o * stride..(o + 1) * stride], dims);
                    add_at_b(rec.jc, dc, rec.jc, dc, u);
                    add_at_r(rec.jc, dc, rec.r, bc);
                    if dg > 0 {
                        add_at_b(rec.jg, dg, rec.jc, dc, ugc);
                        add_at_b(rec.jg, dg, rec.jg, dg, ugp);
                        add_at_r(rec.jg, dg, rec.r, bgp);
                    }
                }
            });
        self.ug.fill(0.0);
        self.bg.fill(0.0);
        if dg > 0 {
            for (ugp, bgp) in self.ug_part.chunks(dg * dg).zip(self.bg_part.chunks(dg)) {
                for (a, b) in self.ug.iter_mut().zip(ugp) {
                    *a += b;
                }
                for (a, b) in self.bg.iter_mut().zip(bgp) {
                    *a += b;
                }
            }
        }
    }
}

/// The Levenberg–Marquardt damping `λ·D` of a diagonal entry `d` of `JᵀJ`: `D` clamped to
/// Ceres' `[min_lm_diagonal, max_lm_diagonal]`.
pub(crate) fn damped(lambda: f64, d: f64) -> f64 {
    lambda * d.clamp(MIN_DIAGONAL, MAX_DIAGONAL)
}

/// Indices of the reduced system that are held fixed.
pub(crate) fn pinned_indices<M: CameraModel>(p: &Problem<M>, dims: Dims) -> Vec<usize> {
    let mut out: Vec<usize> = p.fixed.global.clone();
    for c in 0..dims.n_cam {
        let base = dims.dg + c * dims.dc;
        if p.fixed.poses.contains(&c) {
            out.extend(base..base + 6);
        }
        out.extend(p.fixed.local_of(c).map(|k| base + 6 + k));
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// The reduced system's right-hand side and matrix for one damping value, assembled by row
/// blocks in parallel. Returns `false` when a point block cannot be inverted.
#[allow(clippy::too_many_arguments)]
pub(super) fn assemble_reduced(
    dims: Dims,
    inc: &Incidence,
    nrm: &Normal,
    lambda: f64,
    pinned: &[usize],
    vinv: &mut [Matrix3<f64>],
    s: &mut [f64],
    rhs: &mut [f64],
) -> bool {
    let Dims { dg, dc, n_r, .. } = dims;
    let ok = vinv.par_iter_mut().zip(nrm.v.par_iter()).all(|(vi, v)| {
        let mut a = *v;
        for k in 0..3 {
            a[(k, k)] += damped(lambda, v[(k, k)]);
        }
        match a.try_inverse() {
            Some(inv) => {
                *vi = inv;
                true
            }
            None => false,
        }
    });
    if !ok {
        return false;
    }
    let vinv: &[Matrix3<f64>] = vinv;
    let (s_g, s_c) = s.split_at_mut(dg * n_r);
    let (rhs_g, rhs_c) = rhs.split_at_mut(dg);
    // Shared-intrinsics rows.
    if dg > 0 {
        s_g.fill(0.0);
        for a in 0..dg {
            for b in 0..dg {
                s_g[a * n_r + b] = nrm.ug[a * dg + b];
            }
            s_g[a * n_r + a] += damped(lambda, nrm.ug[a * dg + a]);
            rhs_g[a] = -nrm.bg[a];
            for c in 0..dims.n_cam {
                let ugc = &nrm.ugc[c * dg * dc..(c + 1) * dg * dc];
                s_g[a * n_r + dg + c * dc..a * n_r + dg + (c + 1) * dc]
                    .copy_from_slice(&ugc[a * dc..(a + 1) * dc]);
            }
        }
        let mut y = vec![0.0; dg * 3];
        for (p, vi) in vinv.iter().enumerate() {
            let wg = &nrm.wg[p * dg * 3..(p + 1) * dg * 3];
            mul_block_3x3(wg, dg, vi, &mut y);
            let bp = &nrm.bp[p];
            for a in 0..dg {
                rhs_g[a] += y[a * 3] * bp.x + y[a * 3 + 1] * bp.y + y[a * 3 + 2] * bp.z;
            }
            sub_y_wt(&y, dg, wg, dg, s_g, n_r, 0);
            for &k in inc.pairs_of_point(p) {
                let wo = &nrm.wo[k * dc * 3..(k + 1) * dc * 3];
                sub_y_wt(&y, dg, wo, dc, s_g, n_r, dg + inc.pair_camera[k] * dc);
            }
        }
    }
    // Camera rows.
    s_c.par_chunks_mut(dc * n_r)
        .zip(rhs_c.par_chunks_mut(dc))
        .enumerate()
        .for_each(|(c, (rows, rhs))| {
            rows.fill(0.0);
            let u = &nrm.u[c * dc * dc..(c + 1) * dc * dc];
            let col0 = dg + c * dc;
            for a in 0..dc {
                rows[a * n_r + col0..a * n_r + col0 + dc].copy_from_slice(&u[a * dc..(a + 1) * dc]);
                rows[a * n_r + col0 + a] += damped(lambda, u[a * dc + a]);
                rhs[a] = -nrm.bc[c * dc + a];
            }
            let mut y = [0.0; 3 * (6 + MAX_LOCAL)];
            let y = &mut y[..dc * 3];
            for &k in inc.pairs_of_camera(c) {
                let p = inc.pair_point[k];
                let wo = &nrm.wo[k * dc * 3..(k + 1) * dc * 3];
                mul_block_3x3(wo, dc, &vinv[p], y);
                let bp = &nrm.bp[p];
                for a in 0..dc {
                    rhs[a] += y[a * 3] * bp.x + y[a * 3 + 1] * bp.y + y[a * 3 + 2] * bp.z;
                }
                // Upper block triangle only (cameras j ≥ c); mirrored below.
                for &k2 in inc.pairs_of_point(p) {
                    if inc.pair_camera[k2] < c {
                        continue;
                    }
                    let w2 = &nrm.wo[k2 * dc * 3..(k2 + 1) * dc * 3];
                    sub_y_wt(y, dc, w2, dc, rows, n_r, dg + inc.pair_camera[k2] * dc);
                }
            }
        });
    mirror_upper(s, n_r);
    for &k in pinned {
        for j in 0..n_r {
            s[k * n_r + j] = 0.0;
            s[j * n_r + k] = 0.0;
        }
        s[k * n_r + k] = 1.0;
        rhs[k] = 0.0;
    }
    true
}

/// Copies the upper triangle of a row-major n×n matrix onto its lower triangle (the camera
/// rows assemble only blocks on or above the diagonal; the shared-intrinsics rows are whole).
fn mirror_upper(s: &mut [f64], n: usize) {
    for i in 1..n {
        let (upper, rest) = s.split_at_mut(i * n);
        for (j, v) in rest[..i].iter_mut().enumerate() {
            *v = upper[j * n + i];
        }
    }
}

/// `out = A·M` for row-major `A` (m×3) and a 3×3 `M`.
fn mul_block_3x3(a: &[f64], m: usize, mat: &Matrix3<f64>, out: &mut [f64]) {
    for i in 0..m {
        let (a0, a1, a2) = (a[i * 3], a[i * 3 + 1], a[i * 3 + 2]);
        for j in 0..3 {
            out[i * 3 + j] = a0 * mat[(0, j)] + a1 * mat[(1, j)] + a2 * mat[(2, j)];
        }
    }
}

/// `rows[:, col0..col0+n] −= Y·Wᵀ` for row-major `Y` (m×3) and `W` (n×3).
fn sub_y_wt(y: &[f64], m: usize, w: &[f64], n: usize, rows: &mut [f64], n_r: usize, col0: usize) {
    for a in 0..m {
        let (y0, y1, y2) = (y[a * 3], y[a * 3 + 1], y[a * 3 + 2]);
        let row = &mut rows[a * n_r + col0..a * n_r + col0 + n];
        for (b, v) in row.iter_mut().enumerate() {
            *v -= y0 * w[b * 3] + y1 * w[b * 3 + 1] + y2 * w[b * 3 + 2];
        }
    }
}

/// faer's parallelism for the current rayon pool: its threads, or none on one thread. The
/// factor and the solution are the same to the bit on 1, 2 and 3 threads
/// (`cholesky_is_the_same_on_any_thread_count`, up to a 90-frame fourth-order system).
pub(crate) fn faer_par() -> Par {
    match rayon::current_num_threads() {
        0 | 1 => Par::Seq,
        n => Par::rayon(n),
    }
}

/// Factorises the symmetric positive definite `s` (n×n) in place and solves `s·x = rhs`;
/// `false` if it is not positive definite. The factorisation runs on the current rayon pool
/// (a 90-frame video's fourth-order reduced system is 2,700 unknowns: 6.6 GFLOP a step).
pub(crate) fn cholesky_solve(
    s: &mut [f64],
    n: usize,
    rhs: &mut [f64],
    stack: &mut MemBuffer,
) -> bool {
    let mut a = MatMut::from_column_major_slice_mut(s, n, n);
    let ok = llt::factor::cholesky_in_place(
        a.as_mut(),
        Default::default(),
        faer_par(),
        MemStack::new(stack),
        Default::default(),
    )
    .is_ok();
    if !ok {
        return false;
    }
    let b = MatMut::from_column_major_slice_mut(rhs, n, 1);
    llt::solve::solve_in_place(a.as_ref(), b, Par::Seq, MemStack::new(stack));
    rhs.iter().all(|v| v.is_finite())
}

/// Scratch memory for [`cholesky_solve`] on an n×n system.
pub(crate) fn cholesky_scratch(n: usize) -> MemBuffer {
    MemBuffer::new(
        llt::factor::cholesky_in_place_scratch::<f64>(n, Par::Seq, Default::default())
            .or(llt::solve::solve_in_place_scratch::<f64>(n, 1, Par::Seq)),
    )
}
