//! The cloud's points along a Z-order (Morton) curve over cubic cells, and the uniform grids
//! that order gives for free: at every level of the curve's octree a cell is one contiguous
//! run of the order, so a grid of any cell size is a map from cell to run, and an exact
//! k-nearest-neighbour search in a grid sized to the local point spacing scans a 3×3×3 block
//! of cells (about four times fewer instructions per query on a scanned surface than a k-d
//! tree). Scattered queries descend the same runs as an implicit octree ([`Morton::nearest`]),
//! so the cloud needs no tree at all.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::geometry::bounds;

/// Bits per axis of the Morton codes.
pub(crate) const MORTON_BITS: u32 = 21;

/// Spreads the low 21 bits of `v` two zero bits apart.
fn spread21(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    (x | (x << 2)) & 0x1249_2492_4924_9249
}

/// Gathers every third bit of `v` (from bit 0) into the low 21 bits: the inverse of
/// [`spread21`] (the tests' check of the cell arithmetic).
#[cfg(test)]
fn compact21(v: u64) -> u64 {
    let mut x = v & 0x1249_2492_4924_9249;
    x = (x | (x >> 2)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x >> 4)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x >> 8)) & 0x001f_0000_ff00_00ff;
    x = (x | (x >> 16)) & 0x001f_0000_0000_ffff;
    (x | (x >> 32)) & 0x1f_ffff
}

/// The Z-order code of integer cell coordinates.
fn interleave(c: [u64; 3]) -> u64 {
    spread21(c[0]) | (spread21(c[1]) << 1) | (spread21(c[2]) << 2)
}

/// The keys of the cells of the 3×3×3 block around the cell `key` at `level` that lie in the
/// curve's box, by arithmetic on the interleaved bits: one axis's bits, the others set, plus
/// one carries along that axis alone (and minus one borrows).
fn block_keys(key: u64, level: u32) -> impl Iterator<Item = u64> {
    let x = spread21((1 << level) - 1);
    let [dx, dy, dz] = [x, x << 1, x << 2].map(|m| {
        let v = key & m;
        [
            (v != 0).then(|| v.wrapping_sub(1) & m),
            Some(v),
            (v != m).then(|| (v | !m).wrapping_add(1) & m),
        ]
    });
    dz.into_iter().flatten().flat_map(move |z| {
        dy.into_iter()
            .flatten()
            .flat_map(move |y| dx.into_iter().flatten().map(move |x| x | y | z))
    })
}

/// The points' order along a Z-order curve over cubic cells spanning their bounding box.
pub(crate) struct Morton {
    lo: Vector3<f64>,
    /// Finest cells per metre (the same on every axis: cells are cubes).
    scale: f64,
    /// Point indices in curve order (ties by index).
    pub order: Vec<u32>,
    /// Position of each point in `order`.
    pub rank: Vec<u32>,
    /// The codes in curve order (sorted).
    codes: Vec<u64>,
}

impl Morton {
    /// Orders the `n` points `point(0..n)` (finite, at least one) along the curve.
    pub fn new(n: usize, point: &(impl Fn(usize) -> Vector3<f64> + Sync)) -> Self {
        let (lo, hi) = bounds((0..n).map(point));
        let extent = (hi - lo).max();
        let scale = if extent > 0.0 {
            f64::from((1u32 << MORTON_BITS) - 1) / extent
        } else {
            0.0
        };
        let mut m = Morton {
            lo,
            scale,
            order: Vec::new(),
            rank: Vec::new(),
            codes: Vec::new(),
        };
        let mut keyed: Vec<(u64, u32)> = (0..n)
            .into_par_iter()
            .map(|i| (interleave(m.finest(&point(i))), i as u32))
            .collect();
        keyed.par_sort_unstable();
        // The inverse permutation (scattered writes, serial) beside the two columns.
        let (rank, (codes, order)) = rayon::join(
            || {
                let mut rank = vec![0; n];
                for (pos, &(_, i)) in keyed.iter().enumerate() {
                    rank[i as usize] = pos as u32;
                }
                rank
            },
            || {
                rayon::join(
                    || keyed.par_iter().map(|k| k.0).collect(),
                    || keyed.par_iter().map(|k| k.1).collect(),
                )
            },
        );
        (m.rank, m.codes, m.order) = (rank, codes, order);
        m
    }

    /// The points `point(i)` (`i` as given to [`Morton::new`]) in curve order.
    pub fn gather(&self, point: &(impl Fn(usize) -> Vector3<f64> + Sync)) -> Vec<[f64; 3]> {
        self.order
            .par_iter()
            .map(|&i| point(i as usize).into())
            .collect()
    }

    /// The cell key at `level` of the point at curve position `pos`.
    pub fn key(&self, level: u32, pos: u32) -> u64 {
        self.codes[pos as usize] >> (3 * (MORTON_BITS - level))
    }

    /// Integer coordinates of `p`'s finest cell (clamped to the box).
    fn finest(&self, p: &Vector3<f64>) -> [u64; 3] {
        let max = f64::from((1u32 << MORTON_BITS) - 1);
        let c = (p - self.lo) * self.scale;
        [c.x, c.y, c.z].map(|v| v.clamp(0.0, max) as u64)
    }

    /// Side (m) of the cells at `level` (2^level cells per axis), infinite for a cloud of one
    /// location.
    pub fn cell_size(&self, level: u32) -> f64 {
        f64::from(1u32 << (MORTON_BITS - level)) / self.scale
    }

    /// The finest level whose cells are at least `size` wide (level 0: one cell).
    pub fn level_for(&self, size: f64) -> u32 {
        (0..=MORTON_BITS)
            .rev()
            .find(|&l| self.cell_size(l) >= size)
            .unwrap_or(0)
    }
}

/// Curve neighbours on each side of a scattered query whose k-th nearest distance bounds the
/// query's own ([`Morton::nearest`]).
const WINDOW: usize = 16;

/// Squared distance of two points.
fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

impl Morton {
    /// The first curve position whose code is at least `code`, found by galloping from
    /// `hint` (a neighbouring cell's run is usually near the query's along the curve).
    fn lower_bound(&self, code: u64, hint: usize) -> usize {
        let codes = &self.codes;
        let n = codes.len();
        let hint = hint.min(n);
        // The answer lies in lo..=hi.
        let (mut lo, mut hi) = (0, n);
        let mut step = 1;
        if hint < n && codes[hint] < code {
            lo = hint + 1;
            while hint + step < n {
                if codes[hint + step] >= code {
                    hi = hint + step;
                    break;
                }
                lo = hint + step + 1;
                step *= 2;
            }
        } else {
            hi = hint;
            while step <= hint {
                if codes[hint - step] < code {
                    lo = hint - step + 1;
                    break;
                }
                hi = hint - step;
                step *= 2;
            }
        }
        lo + codes[lo..hi].partition_point(|&c| c < code)
    }

    /// The exact [`K`] nearest neighbours (fewer in a smaller cloud) of the point at curve
    /// position `pos` (`points` in curve order), from the curve's implicit octree (a cell is
    /// a run of the order; its eight children split the run by three bits of the codes):
    /// 1. the k nearest of its ±[`WINDOW`] curve neighbours give a first answer and bound
    ///    the k-th distance by `r`;
    /// 2. the cells at least `r` wide that meet the box `q ± r` hold every neighbour (cell
    ///    coordinates are monotone in each coordinate); their runs are found by galloping
    ///    from `pos`;
    /// 3. depth first, nearest child first: a cell beyond the current k-th distance is
    ///    skipped, a cell of at most [`LEAF`] points is scanned, a larger one split.
    pub fn nearest(&self, points: &[[f64; 3]], pos: u32, scratch: &mut OctreeScratch) -> Nearest {
        let n = points.len();
        let q = points[pos as usize];
        let span = (2 * WINDOW + 1).min(n);
        let first = (pos as usize).saturating_sub(WINDOW).min(n - span);
        let mut best = TopK::new();
        for (p, i) in points[first..first + span].iter().zip(first as u32..) {
            best.offer(dist2(p, &q).to_bits(), i);
        }
        let r2 = best.worst();
        // Widened for the rounding of the distances and of the box's corners.
        let r = f64::from_bits(r2).sqrt() * (1.0 + 1e-9)
            + 1e-12 * (1.0 + q.iter().map(|v| v.abs()).sum::<f64>());
        let level = if best.len < K { 0 } else { self.level_for(r) };
        let shift = MORTON_BITS - level;
        let q3 = Vector3::from(q);
        let below = self.finest(&q3.add_scalar(-r)).map(|v| v >> shift);
        let above = self.finest(&q3.add_scalar(r)).map(|v| v >> shift);
        scratch.stack.clear();
        let mut roots = [Cell::default(); 27];
        let mut count = 0;
        // The cells meeting the box; their runs are looked up when reached (nearest first:
        // by then the k-th distance has usually shrunk below the far ones' distance).
        for cz in below[2]..=above[2] {
            for cy in below[1]..=above[1] {
                for cx in below[0]..=above[0] {
                    roots[count] = self.cell(&q, level, [cx, cy, cz], UNRESOLVED, UNRESOLVED);
                    count += 1;
                }
            }
        }
        let stack = &mut scratch.stack;
        push_nearest_last(stack, &mut roots[..count]);
        let window = first..first + span;
        while let Some(cell) = stack.pop() {
            if cell.gap2 > f64::from_bits(best.worst()) {
                continue;
            }
            let (start, end) = if cell.start == UNRESOLVED {
                let key = interleave(cell.coords);
                self.run(cell.level, key, pos as usize, &mut scratch.runs)
            } else {
                (cell.start as usize, cell.end as usize)
            };
            if start == end {
                continue;
            }
            if end - start <= LEAF || cell.level == MORTON_BITS {
                for (p, i) in points[start..end].iter().zip(start..) {
                    if !window.contains(&i) {
                        best.offer(dist2(p, &q).to_bits(), i as u32);
                    }
                }
                continue;
            }
            // The eight children's runs: the run split by the codes' next three bits.
            let level = cell.level + 1;
            let child_shift = 3 * (MORTON_BITS - level);
            let run = &self.codes[start..end];
            let mut children = [Cell::default(); 8];
            let mut count = 0;
            let mut lo = start;
            for octant in 0..8u64 {
                let hi = if octant == 7 {
                    end
                } else {
                    start + run.partition_point(|&c| (c >> child_shift) & 7 <= octant)
                };
                if hi > lo {
                    let c: [u64; 3] =
                        std::array::from_fn(|a| 2 * cell.coords[a] + ((octant >> a) & 1));
                    children[count] = self.cell(&q, level, c, lo as u32, hi as u32);
                    count += 1;
                }
                lo = hi;
            }
            push_nearest_last(stack, &mut children[..count]);
        }
        best.into_nearest()
    }

    /// The run of the cell `key` at `level`, from `cache` or found by galloping from `hint`.
    fn run(&self, level: u32, key: u64, hint: usize, cache: &mut RunCache) -> (usize, usize) {
        // The level as a leading bit: every (level, key) has its own tag, and none is 0.
        let tag = key | (1 << (3 * level));
        let slot = &mut cache.0[(tag.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 56) as usize];
        if slot.0 == tag {
            return (slot.1 as usize, slot.2 as usize);
        }
        let (start, end) = self.cell_run(level, key, hint);
        *slot = (tag, start as u32, end as u32);
        (start, end)
    }

    /// The run `start..end` of the cell `key` at `level` (empty when the cell holds no
    /// point), found by galloping from `hint`.
    fn cell_run(&self, level: u32, key: u64, hint: usize) -> (usize, usize) {
        let shift = 3 * (MORTON_BITS - level);
        let start = self.lower_bound(key << shift, hint);
        (start, self.lower_bound((key + 1) << shift, start))
    }

    /// The cell at `level` with integer coordinates `c` and run `start..end`, with its
    /// squared distance from `q` (its box widened by a millionth of a cell for the rounding
    /// of the cell coordinates).
    fn cell(&self, q: &[f64; 3], level: u32, c: [u64; 3], start: u32, end: u32) -> Cell {
        let size = self.cell_size(level);
        let pad = 1e-6 * size;
        let gap2 = (0..3)
            .map(|a| {
                let lo = self.lo[a] + c[a] as f64 * size - pad;
                let hi = lo + size + 2.0 * pad;
                (lo - q[a]).max(q[a] - hi).max(0.0).powi(2)
            })
            .sum();
        Cell {
            level,
            coords: c,
            start,
            end,
            gap2,
        }
    }
}

/// The run of a cell of [`Morton::nearest`] not looked up yet.
const UNRESOLVED: u32 = u32::MAX;

/// Largest run [`Morton::nearest`] scans without splitting it.
const LEAF: usize = 32;

/// A cell of the curve's octree met by [`Morton::nearest`].
#[derive(Clone, Copy, Default)]
struct Cell {
    level: u32,
    coords: [u64; 3],
    start: u32,
    end: u32,
    /// Squared distance from the query to the cell's box.
    gap2: f64,
}

/// Per-thread scratch of [`Morton::nearest`]: its stack of cells, and the runs of the cells
/// it started from lately (queries in curve order share most of them).
#[derive(Default)]
pub(crate) struct OctreeScratch {
    stack: Vec<Cell>,
    runs: RunCache,
}

/// A direct-mapped cache of 256 cells' runs: (tag, start, end), tag 0 when empty.
struct RunCache([(u64, u32, u32); 256]);

impl Default for RunCache {
    fn default() -> Self {
        RunCache([(0, 0, 0); 256])
    }
}

/// Pushes `cells` so that the nearest is popped first.
fn push_nearest_last(stack: &mut Vec<Cell>, cells: &mut [Cell]) {
    cells.sort_unstable_by(|a, b| b.gap2.total_cmp(&a.gap2));
    stack.extend_from_slice(cells);
}

/// The [`K`] smallest keys offered (squared distances' bits) with their positions, sorted;
/// of equal keys the first offered.
struct TopK {
    keys: [u64; K],
    pos: [u32; K],
    len: usize,
}

impl TopK {
    fn new() -> Self {
        TopK {
            keys: [u64::MAX; K],
            pos: [0; K],
            len: 0,
        }
    }

    /// The k-th smallest key so far (`u64::MAX` until k are held).
    fn worst(&self) -> u64 {
        self.keys[K - 1]
    }

    fn offer(&mut self, key: u64, pos: u32) {
        if key >= self.keys[K - 1] {
            return;
        }
        let mut i = self.len.min(K - 1);
        while i > 0 && key < self.keys[i - 1] {
            self.keys[i] = self.keys[i - 1];
            self.pos[i] = self.pos[i - 1];
            i -= 1;
        }
        self.keys[i] = key;
        self.pos[i] = pos;
        self.len = (self.len + 1).min(K);
    }

    fn into_nearest(self) -> Nearest {
        let mut out = Nearest::new();
        out.len = self.len;
        out.pos = self.pos;
        for (d2, &key) in out.d2.iter_mut().zip(&self.keys[..self.len]) {
            *d2 = f64::from_bits(key);
        }
        out
    }
}

/// Hashes a cell code by one multiplication (the codes are distinct integers; SipHash's
/// protection against chosen keys buys nothing here and costs a third of a query). Also the
/// hasher of the network's grid cells (`network::components`).
#[derive(Default)]
pub(crate) struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    /// Word by word (a grid cell's three coordinates are three words; byte by byte, their
    /// hash was 7 % of a million-point network pass). The rotation brings the previous
    /// product's well-mixed high bits down to the low bits a table indexes by.
    fn write(&mut self, bytes: &[u8]) {
        for word in bytes.chunks(8) {
            let mut le = [0u8; 8];
            le[..word.len()].copy_from_slice(word);
            self.0 = (self.0.rotate_left(29) ^ u64::from_le_bytes(le))
                .wrapping_mul(0x9e37_79b9_7f4a_7c15);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (v ^ (v >> 29)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    }
}

/// Entries of [`Grid::covering`]'s table of cells seen (the top 12 bits of a hash).
const SEEN: usize = 1 << 12;

/// The cells of one level of the curve's octree: each non-empty cell's run of positions.
pub(crate) struct Grid {
    level: u32,
    /// Cell side (m).
    size: f64,
    runs: HashMap<u64, (u32, u32), BuildHasherDefault<CellHasher>>,
}

/// How far beyond the last query's k-th squared distance a query ranks its candidates first
/// (1.2²: neighbouring points have similar spacing).
const GUESS: f64 = 1.44;

/// Neighbours a grid query returns (the cloud's normal neighbourhood).
pub(crate) const K: usize = 16;

/// The k nearest neighbours of one query: positions along the curve and squared distances,
/// nearest first.
#[derive(Clone, Copy)]
pub(crate) struct Nearest {
    pub pos: [u32; K],
    pub d2: [f64; K],
    pub len: usize,
}

impl Nearest {
    fn new() -> Self {
        Nearest {
            pos: [0; K],
            d2: [f64::INFINITY; K],
            len: 0,
        }
    }
}

/// Per-thread scratch of [`Grid::nearest_in_cell`]: the block's points (coordinates by axis,
/// so that the distance loop vectorises), the candidates of the current query, and the last
/// query's k-th squared distance.
#[derive(Default)]
pub(crate) struct BlockScratch {
    pos: Vec<u32>,
    xyz: [Vec<f64>; 3],
    /// The block's non-empty cells: their points' range in `pos` and `xyz`, and their box
    /// (widened by a millionth of a cell for the rounding of the cell coordinates).
    cells: Vec<(usize, usize, [f64; 3], [f64; 3])>,
    ranked: Vec<(u64, u32)>,
    last: f64,
}

impl BlockScratch {
    fn clear(&mut self) {
        self.pos.clear();
        self.xyz.iter_mut().for_each(Vec::clear);
        self.cells.clear();
    }

    fn push_run(&mut self, points: &[[f64; 3]], start: u32, end: u32, lo: [f64; 3], hi: [f64; 3]) {
        let first = self.pos.len();
        self.cells
            .push((first, first + (end - start) as usize, lo, hi));
        self.pos.extend(start..end);
        let run = &points[start as usize..end as usize];
        for (a, axis) in self.xyz.iter_mut().enumerate() {
            axis.extend(run.iter().map(|p| p[a]));
        }
    }

    /// The [`K`] nearest of the block's points to `q` within squared distance `limit` (fewer
    /// when fewer are that near), nearest first.
    fn nearest(&mut self, q: &[f64; 3], limit: f64) -> Nearest {
        self.ranked.resize(self.pos.len(), (0, 0));
        let [xs, ys, zs] = &self.xyz;
        // Branch-free compaction: every candidate is written, the kept ones advance. A
        // squared distance is never negative, so its bits order like its value: integer
        // comparisons rank the candidates. Cells whose box lies beyond `limit` are skipped.
        let mut kept = 0;
        for &(first, end, lo, hi) in &self.cells {
            let gap: f64 = (0..3)
                .map(|a| (lo[a] - q[a]).max(q[a] - hi[a]).max(0.0).powi(2))
                .sum();
            if gap > limit {
                continue;
            }
            let cell = xs[first..end]
                .iter()
                .zip(&ys[first..end])
                .zip(&zs[first..end])
                .zip(&self.pos[first..end]);
            for (((&x, &y), &z), &pos) in cell {
                let d2 = (x - q[0]).powi(2) + (y - q[1]).powi(2) + (z - q[2]).powi(2);
                self.ranked[kept] = (d2.to_bits(), pos);
                kept += usize::from(d2 <= limit);
            }
        }
        // Insertion into the sorted best K (the candidates are few: those within `limit`);
        // the earlier of two at the same distance first, so the order is the block's.
        let mut best = TopK::new();
        for &(key, pos) in &self.ranked[..kept] {
            best.offer(key, pos);
        }
        best.into_nearest()
    }
}

impl Grid {
    /// The grid of `morton`'s cells at `level` around the cells `query_cells` (keys, sorted):
    /// the runs of those cells and of their 26 neighbours, found by galloping along the codes
    /// in key order. Much cheaper than indexing every cell of the cloud when the queries are
    /// a band around one pipe.
    pub fn covering(morton: &Morton, level: u32, query_cells: &[u64]) -> Self {
        // The runs of the non-empty cells among `keys` (sorted): each chunk gallops along
        // the codes from the previous key's run.
        let runs_of = |keys: &[u64]| -> Vec<(u64, (u32, u32))> {
            keys.par_chunks(1024)
                .flat_map_iter(|chunk| {
                    let mut pos = 0;
                    chunk.iter().filter_map(move |&key| {
                        let (start, end) = morton.cell_run(level, key, pos);
                        pos = end;
                        (end > start).then_some((key, (start as u32, end as u32)))
                    })
                })
                .collect()
        };
        let mut runs: HashMap<u64, (u32, u32), BuildHasherDefault<CellHasher>> =
            runs_of(query_cells).into_iter().collect();
        // The block cells that are not query cells (around a band, nearly all empty).
        // Neighbouring query cells (along the curve) share most of their block cells: a
        // small direct-mapped table of the chunk's cells seen skips most repeats before the
        // map is probed, and each chunk's are deduplicated before they are gathered and
        // sorted.
        let parts: Vec<Vec<u64>> = query_cells
            .par_chunks(1024)
            .map(|chunk| {
                let mut seen = vec![u64::MAX; SEEN];
                let mut part: Vec<u64> = Vec::new();
                for k in chunk.iter().flat_map(|&key| block_keys(key, level)) {
                    let slot = &mut seen[(k.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 52) as usize];
                    if *slot != k {
                        *slot = k;
                        if !runs.contains_key(&k) {
                            part.push(k);
                        }
                    }
                }
                part.sort_unstable();
                part.dedup();
                part
            })
            .collect();
        let mut others = parts.concat();
        others.par_sort_unstable();
        others.dedup();
        // One sorted pass finds the few that hold points.
        runs.extend(runs_of(&others));
        Grid {
            level,
            size: morton.cell_size(level),
            runs,
        }
    }

    /// The exact [`K`] nearest neighbours (positions along the curve; `points` in curve
    /// order) of each query position in `queries`, all in one cell. A query whose
    /// neighbourhood may reach beyond the cell's 3×3×3 block (its k-th distance exceeds the
    /// distance to the block's boundary, or the block holds fewer than k points) gets `None`.
    pub fn nearest_in_cell(
        &self,
        morton: &Morton,
        points: &[[f64; 3]],
        queries: &[u32],
        scratch: &mut BlockScratch,
        mut found: impl FnMut(u32, Option<&Nearest>),
    ) {
        let Some(&first) = queries.first() else {
            return;
        };
        let cells = 1i64 << self.level;
        let shift = MORTON_BITS - self.level;
        let cell = morton
            .finest(&Vector3::from(points[first as usize]))
            .map(|v| (v >> shift) as i64);
        scratch.clear();
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let c = [cell[0] + dx, cell[1] + dy, cell[2] + dz];
                    if c.iter().any(|&v| v < 0 || v >= cells) {
                        continue;
                    }
                    let key = interleave(c.map(|v| v as u64));
                    if let Some(&(s, e)) = self.runs.get(&key) {
                        let pad = 1e-6 * self.size;
                        let lo: [f64; 3] =
                            std::array::from_fn(|a| morton.lo[a] + c[a] as f64 * self.size - pad);
                        let hi = lo.map(|v| v + self.size + 2.0 * pad);
                        scratch.push_run(points, s, e, lo, hi);
                    }
                }
            }
        }
        // The distance from a query to the block's boundary along each axis; a side at the
        // edge of the cloud's box has nothing beyond it.
        let lo = morton.lo;
        let bound = |axis: usize, q: f64| -> f64 {
            let below = if cell[axis] > 0 {
                q - (lo[axis] + (cell[axis] - 1) as f64 * self.size)
            } else {
                f64::INFINITY
            };
            let above = if cell[axis] + 1 < cells {
                lo[axis] + (cell[axis] + 2) as f64 * self.size - q
            } else {
                f64::INFINITY
            };
            below.min(above)
        };
        for &q in queries {
            let p = points[q as usize];
            // A margin of a millionth of a cell for the rounding of the cell coordinates.
            let reach =
                (0..3).map(|a| bound(a, p[a])).fold(f64::INFINITY, f64::min) - 1e-6 * self.size;
            let limit = reach * reach;
            // The previous query's k-th distance, widened, usually holds k points and a
            // fifth of the block: only those are ranked. Too few: rank the whole block.
            let guess = (scratch.last * GUESS).min(limit);
            let mut best = scratch.nearest(&p, guess);
            if best.len < K && guess < limit {
                best = scratch.nearest(&p, limit);
            }
            let exact = best.len == K && reach > 0.0 && best.d2[K - 1] <= limit;
            if exact {
                scratch.last = best.d2[K - 1];
            }
            found(q, exact.then_some(&best));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Brute-force k nearest squared distances.
    fn brute(points: &[[f64; 3]], q: usize) -> Vec<f64> {
        let mut d: Vec<f64> = points
            .iter()
            .map(|x| (0..3).map(|a| (x[a] - points[q][a]).powi(2)).sum())
            .collect();
        d.sort_by(f64::total_cmp);
        d.truncate(K);
        d
    }

    #[test]
    fn block_keys_are_the_neighbouring_cells_in_the_box() {
        // Against coordinates: every cell of a 4-level grid, corners and faces included.
        let level = 2;
        for key in 0..64u64 {
            let c = [key, key >> 1, key >> 2].map(compact21);
            let mut want: Vec<u64> = Vec::new();
            for n in 0..27i64 {
                let m: [i64; 3] =
                    std::array::from_fn(|a| c[a] as i64 + [n % 3, n / 3 % 3, n / 9][a] - 1);
                if m.iter().all(|v| (0..4).contains(v)) {
                    want.push(interleave(m.map(|v| v as u64)));
                }
            }
            let mut got: Vec<u64> = block_keys(key, level).collect();
            want.sort_unstable();
            got.sort_unstable();
            assert_eq!(got, want, "cell {c:?}");
        }
    }

    #[test]
    fn compact_inverts_spread() {
        for v in [0u64, 1, 2, 12_345, 0x1f_ffff, 0x15_5555] {
            assert_eq!(compact21(spread21(v)), v);
            assert_eq!(compact21(interleave([7, v, 3]) >> 1), v);
        }
    }

    /// A dense plane, a sparse volume and duplicated points, in a box far from cubic.
    fn mixed_cloud() -> Vec<Vector3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut pts: Vec<Vector3<f64>> = (0..6000)
            .map(|_| Vector3::new(rng.random_range(0.0..2.0), rng.random_range(0.0..0.3), 0.1))
            .collect();
        pts.extend((0..600).map(|_| {
            Vector3::new(
                rng.random_range(0.0..2.0),
                rng.random_range(0.0..0.3),
                rng.random_range(0.0..0.5),
            )
        }));
        pts.extend(pts[..200].to_vec());
        pts
    }

    #[test]
    fn octree_neighbours_are_exact() {
        // Every point of the mixed cloud, and of a cloud smaller than k: the distances
        // bit-exact against brute force, each returned position at its distance.
        let mut clouds = vec![mixed_cloud()];
        clouds.push(clouds[0][..11].to_vec());
        for pts in clouds {
            let morton = Morton::new(pts.len(), &|i| pts[i]);
            let sorted = morton.gather(&|i| pts[i]);
            let mut scratch = OctreeScratch::default();
            for q in 0..sorted.len() {
                let nb = morton.nearest(&sorted, q as u32, &mut scratch);
                assert_eq!(&nb.d2[..nb.len], &brute(&sorted, q)[..], "query {q}");
                for (&p, &d2) in nb.pos[..nb.len].iter().zip(&nb.d2) {
                    assert_eq!(dist2(&sorted[p as usize], &sorted[q]), d2);
                }
                let mut distinct = nb.pos[..nb.len].to_vec();
                distinct.sort_unstable();
                distinct.dedup();
                assert_eq!(distinct.len(), nb.len);
            }
        }
    }

    #[test]
    fn grid_neighbours_are_exact_or_refused() {
        let pts = mixed_cloud();
        let morton = Morton::new(pts.len(), &|i| pts[i]);
        let sorted = morton.gather(&|i| pts[i]);
        // The 90th percentile of the 16th-neighbour distances: a grid at least that coarse
        // answers at least nine queries in ten (every block reaches one cell beyond its
        // query), finer grids refuse more; every answer is exact.
        let mut reach: Vec<f64> = (0..sorted.len())
            .map(|q| brute(&sorted, q)[K - 1].sqrt())
            .collect();
        reach.sort_by(f64::total_cmp);
        let sized = morton.level_for(reach[reach.len() * 9 / 10]);
        for level in [sized - 2, sized - 1, sized, sized + 1] {
            let mut keys: Vec<u64> = (0..sorted.len() as u32)
                .map(|p| morton.key(level, p))
                .collect();
            keys.dedup();
            let grid = Grid::covering(&morton, level, &keys);
            let mut scratch = BlockScratch::default();
            let (mut answered, mut start) = (0, 0);
            while start < sorted.len() {
                let key = morton.key(level, start as u32);
                let len = (start..sorted.len())
                    .take_while(|&p| morton.key(level, p as u32) == key)
                    .count();
                let queries: Vec<u32> = (start as u32..(start + len) as u32).collect();
                grid.nearest_in_cell(&morton, &sorted, &queries, &mut scratch, |q, nb| {
                    if let Some(nb) = nb {
                        assert_eq!(&nb.d2[..], &brute(&sorted, q as usize)[..]);
                        for (&p, &d2) in nb.pos.iter().zip(&nb.d2) {
                            let (x, y) = (sorted[p as usize], sorted[q as usize]);
                            let e: f64 = (0..3).map(|a| (x[a] - y[a]).powi(2)).sum();
                            assert_eq!(e, d2);
                        }
                        answered += 1;
                    }
                });
                start += len;
            }
            if level <= sized {
                assert!(
                    10 * answered >= 9 * sorted.len(),
                    "level {level}: {answered}"
                );
            } else {
                assert!(
                    10 * answered < 9 * sorted.len(),
                    "level {level}: {answered}"
                );
            }
        }
    }
}
