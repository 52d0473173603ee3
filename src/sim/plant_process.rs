//! A process room, built unlike [`super::plant::plant_room`]: the same enclosure and scanner,
//! other fittings and other ways for a straight pipe to end.
//!
//! - a **vertical tank** on the floor (radius 0.7–0.9 m, larger than any pipe) with a nozzle
//!   and a **flange pair** at which the main line starts, and a second line welded straight
//!   into its shell (the pipe ends where its surface meets the tank's);
//! - the main line along x: a **concentric reducer** (a cone two sizes down, ASME B16.9-like
//!   length), a **flange pair** mid-run, a **horizontal tee** whose branch runs along y into a
//!   wall, then three long-radius elbows with a **short spool** (0.35–0.5 m) between two of
//!   them, and a top run into the wall that **rests on a steel beam**.
//!
//! The truth lists every straight segment with its axis ends where its bare straight surface
//! ends (a flange face, a reducer's end, an elbow's tangent point, a wall, the tank's shell,
//! the run's surface for the branch). No code here calls the algorithms it judges.

use nalgebra::Vector3;
use parry3d_f64::math::{Pose, Vector};
use parry3d_f64::shape::SharedShape;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::plant_builder::{Builder, PipeSize, draw_size, round_bounds};
use super::plant_room::{Part, PlantRoom, SIM_PIPE_SIZES};

/// Points on each end circle of a reducer's cone (its convex hull is the solid).
const REDUCER_RIM_POINTS: usize = 64;
/// Thickness of one flange of a pair (m), about a class-150 weld-neck flange's.
const FLANGE_THICKNESS_M: f64 = 0.025;
/// Length of a tank nozzle's stub, from the shell to its flange (m).
const NOZZLE_STUB_M: f64 = 0.15;

/// A flange's outside radius for a pipe of `size` (class 150 flanges reach about 1.6–1.8 ×
/// the pipe's outside radius on these sizes).
fn flange_radius(size: PipeSize) -> f64 {
    size.radius() + 0.05 + 0.1 * size.od_m()
}

/// `size` `steps` entries down the simulator's size table.
fn smaller(size: PipeSize, steps: usize) -> PipeSize {
    let k = SIM_PIPE_SIZES
        .iter()
        .position(|s| s.0 == size.nps)
        .unwrap_or(0)
        .saturating_sub(steps);
    let (nps, dn, od_mm) = SIM_PIPE_SIZES[k];
    PipeSize {
        nps,
        dn,
        od_mm,
        material: size.material,
    }
}

impl Builder {
    /// A concentric reducer from `a` (pipe `big`) to `b` (pipe `small`): the convex hull of
    /// its two end circles, one object.
    fn add_reducer(&mut self, a: [f64; 3], b: [f64; 3], big: PipeSize, small: PipeSize) {
        let (pa, pb) = (Vector3::from(a), Vector3::from(b));
        let d = (pb - pa).normalize();
        // The rim's frame turned by half a turn from the plane's basis (as first written).
        let (u, w) = crate::geometry::plane_basis(&d);
        let (u, w) = (-u, -w);
        let mut rim = Vec::with_capacity(2 * REDUCER_RIM_POINTS);
        for (centre, r) in [(pa, big.radius()), (pb, small.radius())] {
            for k in 0..REDUCER_RIM_POINTS {
                let t = std::f64::consts::TAU * k as f64 / REDUCER_RIM_POINTS as f64;
                let p = centre + (u * t.cos() + w * t.sin()) * r;
                rim.push(Vector::new(p.x, p.y, p.z));
            }
        }
        let id = self.object("reducer", round_bounds(a, b, big.radius()));
        if let Some(hull) = SharedShape::convex_hull(&rim) {
            self.add((Pose::IDENTITY, hull), Part::Object(id), 0.35);
        }
    }

    /// A pair of flanges bolted face to face about `joint` on an axis along `d`, for pipe
    /// `size`; returns the two outer faces' centres (where the pipes on either side start).
    fn add_flange_pair(
        &mut self,
        joint: Vector3<f64>,
        d: Vector3<f64>,
        size: PipeSize,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let r = flange_radius(size);
        let (before, after) = (
            joint - d * FLANGE_THICKNESS_M,
            joint + d * FLANGE_THICKNESS_M,
        );
        self.add_round("flange", before.into(), joint.into(), r, 0.4);
        self.add_round("flange", joint.into(), after.into(), r, 0.4);
        (before, after)
    }
}

/// Draws a process room from `seed` (module documentation).
#[must_use]
pub fn process_room(seed: u64) -> PlantRoom {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7A_4C0B);
    let length = rng.random_range(8.0..10.0);
    let width = rng.random_range(6.0..7.0);
    let height = rng.random_range(3.6..4.0);
    let mut b = Builder::new();
    b.enclosure(length, width, height);

    // The tank, standing on the floor near the wall x = 0.
    let tank_r = rng.random_range(0.7..0.9);
    let (xt, yt) = (tank_r + 0.3, 0.2 * width);
    let tank_h = rng.random_range(2.3..2.6);
    b.add_round("tank", [xt, yt, 0.0], [xt, yt, tank_h], tank_r, 0.5);

    // The main line along +x at (yt, z0), leaving the tank's nozzle through a flange pair.
    let big = draw_size(&mut rng, 3, 5);
    let mid = smaller(big, 2);
    let z0 = rng.random_range(0.9..1.1);
    let x = Vector3::x();
    let shell = Vector3::new(xt + tank_r, yt, z0);
    let stub_end = shell + x * NOZZLE_STUB_M;
    b.add_round(
        "nozzle",
        (shell - x * 0.1).into(),
        stub_end.into(),
        big.radius(),
        0.4,
    );
    let (_, a1_start) = b.add_flange_pair(stub_end + x * FLANGE_THICKNESS_M, x, big);
    // The reducer (its length about one large outside diameter, as B16.9 gives).
    let xr = rng.random_range(0.36..0.42) * length;
    let reducer_len = big.od_m().max(0.1);
    b.add_pipe("main", a1_start.into(), [xr, yt, z0], big, 0.45);
    b.add_reducer([xr, yt, z0], [xr + reducer_len, yt, z0], big, mid);
    // A flange pair mid-run.
    let xf = rng.random_range(0.52..0.56) * length;
    let (f_in, f_out) = b.add_flange_pair(Vector3::new(xf, yt, z0), x, mid);
    b.add_pipe("main", [xr + reducer_len, yt, z0], f_in.into(), mid, 0.45);
    // On to the first elbow; a tee's branch leaves along +y into the wall y = W.
    let xe = rng.random_range(0.8..0.84) * length;
    let bend = 1.5 * mid.od_m();
    b.add_pipe("main", f_out.into(), [xe - bend, yt, z0], mid, 0.45);
    let branch = draw_size(&mut rng, 0, 1);
    let xtee = rng.random_range(0.64..0.68) * length;
    let on_run = yt + (mid.radius().powi(2) - branch.radius().powi(2)).sqrt();
    b.add_pipe("branch", [xtee, on_run, z0], [xtee, width, z0], branch, 0.5);
    // Up, a short spool back along −y, and the top run along +x into the wall x = L.
    let z_top = height - rng.random_range(0.6..0.8);
    b.add_elbow([xe - bend, yt, z0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], mid);
    b.add_pipe(
        "main",
        [xe, yt, z0 + bend],
        [xe, yt, z_top - bend],
        mid,
        0.45,
    );
    b.add_elbow(
        [xe, yt, z_top - bend],
        [0.0, 0.0, 1.0],
        [0.0, -1.0, 0.0],
        mid,
    );
    let spool = rng.random_range(0.35..0.5);
    let ys = yt - bend - spool;
    b.add_pipe("main", [xe, yt - bend, z_top], [xe, ys, z_top], mid, 0.45);
    b.add_elbow([xe, ys, z_top], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], mid);
    let top_y = ys - bend;
    b.add_pipe(
        "main",
        [xe + bend, top_y, z_top],
        [length, top_y, z_top],
        mid,
        0.45,
    );
    // The steel beam the top run rests on, out of the wall y = 0.
    let xb = 0.5 * (xe + bend + length);
    b.add_box(
        "beam",
        [xb - 0.1, 0.0, z_top - mid.radius() - 0.3],
        [xb + 0.1, 0.5 * width, z_top - mid.radius()],
        0.3,
    );

    // A second line welded into the tank's shell along +y at z1, into the wall y = W.
    let second = draw_size(&mut rng, 1, 2);
    let z1 = rng.random_range(1.7..1.9_f64).min(tank_h - 0.3);
    let at_shell = yt + (tank_r.powi(2) - second.radius().powi(2)).sqrt();
    b.add_pipe(
        "tank-line",
        [xt, at_shell, z1],
        [xt, width, z1],
        second,
        0.5,
    );

    b.finish(seed, [length, width, height])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The truth's segments: the reducer joins two sizes two steps apart, the short spool is
    /// 0.35–0.5 m, each segment's ends are where the shapes say, and the tank is wider than any
    /// pipe the search looks for.
    #[test]
    fn the_process_room_holds_what_its_truth_says() {
        for seed in 1..5 {
            let room = process_room(seed);
            let t = &room.truth;
            assert_eq!(t.segments.len(), 8, "seed {seed}");
            let lengths: Vec<f64> = t.segments.iter().map(|s| s.length()).collect();
            assert!(
                lengths.iter().any(|&l| (0.35..=0.5).contains(&l)),
                "seed {seed}: {lengths:?}"
            );
            assert!(lengths.iter().all(|&l| l > 0.3), "seed {seed}: {lengths:?}");
            let kinds: Vec<&str> = t.objects.iter().map(|o| o.kind.as_str()).collect();
            for kind in ["tank", "reducer", "flange", "beam", "elbow"] {
                assert!(kinds.contains(&kind), "seed {seed}: no {kind}");
            }
            assert_eq!(kinds.iter().filter(|k| **k == "flange").count(), 4);
            let main: Vec<_> = t.segments.iter().filter(|s| s.run == "main").collect();
            let step = |nps: &str| SIM_PIPE_SIZES.iter().position(|s| s.0 == nps).unwrap();
            assert_eq!(step(&main[0].nps), step(&main[1].nps) + 2, "seed {seed}");
            // Every shape is a valid solid and the room's compound holds them all.
            assert_eq!(room.parts.len(), room.reflectance.len());
        }
    }
}
