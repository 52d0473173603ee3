//! Plant rooms: a room full of pipes, fittings and equipment built from parry3d
//! shapes, and a terrestrial laser scanner that ray-casts it from one or more stations through
//! parry's bounding-volume hierarchy (shadows and occlusions, range noise, mixed pixels at
//! depth edges, intensity).
//!
//! The room (z up, metres; floor `z = 0`, walls at `x = 0`, `x = L`, `y = 0`, `y = W`):
//! - a **riser and header**: a vertical pipe from the floor, a long-radius elbow (bend radius
//!   1.5 × the nominal diameter) and a horizontal run into the wall `x = L`;
//! - a **valved header** along `y` from wall to wall, a flanged gate valve splitting it in two
//!   segments, a **tee** with a smaller branch down to a **pump** (volute housing, motor, plinth),
//!   flanged at the pump's nozzle, and floor **supports** under the header;
//! - a **small-bore line** along a wall on brackets, turning down into the floor through an
//!   elbow;
//! - **conduits** under the ceiling, a **column**, walls, floor and ceiling.
//!
//! Sizes are drawn from ASME B36.10M outside diameters (carbon steel and stainless steel share
//! them). The truth lists every straight pipe segment (axis endpoints where the bare pipe's
//! straight surface ends: a floor or wall face, an elbow's tangent point, a valve's flange face,
//! the header's surface for the branch) and every other object. No code here calls the
//! algorithms it judges.

use nalgebra::{Point3, Vector3};
use parry3d_f64::math::Vector;
use parry3d_f64::query::Ray;
use parry3d_f64::shape::CompositeShapeRef;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::plant_builder::{Builder, draw_size};
pub use super::plant_room::{
    Material, ObjectTruth, Part, PipeSegmentTruth, PlantRoom, PlantTruth, SIM_PIPE_SIZES, ScanTruth,
};
use crate::io::ply::PointCloud;
use crate::robust::standard_normal as gaussian;

/// How to scan a plant room.
#[derive(Clone, Debug, PartialEq)]
pub struct PlantScanConfig {
    /// Angular step of the scan grid (rad), azimuth and elevation.
    pub step_rad: f64,
    /// Range noise σ (m).
    pub range_noise_m: f64,
    /// Exit beam diameter (m) and divergence (rad): the footprint a mixed pixel blends over.
    pub beam_diameter_m: f64,
    /// See [`Self::beam_diameter_m`].
    pub beam_divergence_rad: f64,
    /// Lowest and highest elevation (rad).
    pub elevation_range_rad: (f64, f64),
    /// Number of stations (1 to 4), placed in the room's free floor area.
    pub stations: usize,
}

impl Default for PlantScanConfig {
    fn default() -> Self {
        PlantScanConfig {
            step_rad: 3e-3,
            range_noise_m: 1.5e-3,
            beam_diameter_m: 3e-3,
            beam_divergence_rad: 0.3e-3,
            elevation_range_rad: (-70f64.to_radians(), 85f64.to_radians()),
            stations: 2,
        }
    }
}

/// Which room `simulate plant` draws.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PlantLayout {
    /// A riser and header, a valved header with a tee down to a pump, a small-bore line,
    /// conduits and a column ([`plant_room`]).
    #[default]
    RiserHeader,
    /// A tank with a flanged nozzle and a line welded into its shell, a reducer, a flange
    /// pair, a horizontal tee, a short spool between elbows and a run on a beam
    /// ([`super::plant_process::process_room`]).
    Process,
}

impl PlantLayout {
    /// The room of `seed` in this layout.
    #[must_use]
    pub fn room(self, seed: u64) -> PlantRoom {
        match self {
            PlantLayout::RiserHeader => plant_room(seed),
            PlantLayout::Process => super::plant_process::process_room(seed),
        }
    }
}

/// Draws a plant room from `seed`.
///
/// Kept whole (one function over 150 lines): a scene description read top to bottom, its
/// objects drawn in order from one random stream (the order of the draws is the room).
#[must_use]
pub fn plant_room(seed: u64) -> PlantRoom {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9_1A47);
    let length = rng.random_range(7.0..9.0);
    let width = rng.random_range(5.5..6.5);
    let height = rng.random_range(3.3..3.8);
    let mut b = Builder::new();
    b.enclosure(length, width, height);

    // The riser and header: up from the floor at (x1, y1), elbow toward +x, into the wall.
    let riser = draw_size(&mut rng, 2, 5);
    let x1 = rng.random_range(0.25..0.35) * length;
    let y1 = rng.random_range(0.2..0.3) * width;
    let z1 = height - rng.random_range(0.45..0.7);
    let bend = 1.5 * riser.od_m();
    b.add_pipe("riser", [x1, y1, 0.0], [x1, y1, z1 - bend], riser, 0.4);
    b.add_elbow([x1, y1, z1 - bend], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], riser);
    b.add_pipe("riser", [x1 + bend, y1, z1], [length, y1, z1], riser, 0.4);

    // The valved header along y at x2, height z2, wall to wall.
    let header = draw_size(&mut rng, 2, 4);
    let x2 = rng.random_range(0.55..0.65) * length;
    let z2 = rng.random_range(2.0f64..2.4).min(z1 - 0.5);
    let r2 = header.radius();
    let valve_y = rng.random_range(0.6..0.7) * width;
    let valve_half = 0.2 + header.od_m();
    let flange = 0.03;
    let (ya, yb) = (valve_y - valve_half, valve_y + valve_half);
    b.add_pipe("header", [x2, 0.0, z2], [x2, ya, z2], header, 0.45);
    b.add_pipe("header", [x2, yb, z2], [x2, width, z2], header, 0.45);
    let flange_r = r2 + 0.04 + 0.1 * header.od_m();
    for (p, q) in [(ya, ya + flange), (yb - flange, yb)] {
        b.add_round("flange", [x2, p, z2], [x2, q, z2], flange_r, 0.4);
    }
    let body = r2 + 0.03;
    b.add_box(
        "valve",
        [x2 - body, ya + flange, z2 - body],
        [x2 + body, yb - flange, z2 + body],
        0.25,
    );
    b.add_round(
        "valve",
        [x2, valve_y, z2 + body],
        [x2, valve_y, z2 + body + 0.25],
        0.015,
        0.3,
    );
    b.add_round(
        "valve",
        [x2, valve_y, z2 + body + 0.25],
        [x2, valve_y, z2 + body + 0.27],
        0.12 + r2,
        0.3,
    );
    // Floor supports under the header (a post and a saddle plate touching the pipe).
    for y in [0.1 * width, 0.85 * width] {
        b.add_box(
            "support",
            [x2 - 0.05, y - 0.05, 0.0],
            [x2 + 0.05, y + 0.05, z2 - r2 - 0.01],
            0.3,
        );
        b.add_box(
            "support",
            [x2 - r2 - 0.03, y - 0.04, z2 - r2 - 0.01],
            [x2 + r2 + 0.03, y + 0.04, z2 - r2],
            0.3,
        );
    }

    // The tee and the branch down to the pump's nozzle.
    let branch = draw_size(&mut rng, 0, 1);
    let yt = rng.random_range(0.3..0.4) * width;
    let housing_r = rng.random_range(0.28..0.36);
    let housing_z = housing_r + 0.25;
    let nozzle_top = housing_z + housing_r + 0.08;
    let branch_flange = branch.radius() + 0.04;
    b.add_round(
        "flange",
        [x2, yt, nozzle_top],
        [x2, yt, nozzle_top + 2.0 * flange],
        branch_flange,
        0.4,
    );
    b.add_round(
        "housing",
        [x2, yt, housing_z + housing_r - 0.02],
        [x2, yt, nozzle_top],
        branch.radius() + 0.01,
        0.35,
    );
    b.add_pipe(
        "branch",
        [x2, yt, nozzle_top + 2.0 * flange],
        [
            x2,
            yt,
            z2 - r2 * (1.0 - (branch.radius() / r2).powi(2)).sqrt(),
        ],
        branch,
        0.45,
    );
    // The volute housing (axis along x), the motor and the plinth.
    let half = 0.2;
    b.add_round(
        "housing",
        [x2 - half, yt, housing_z],
        [x2 + half, yt, housing_z],
        housing_r,
        0.35,
    );
    b.add_box(
        "plinth",
        [x2 - 0.5, yt - housing_r - 0.1, 0.0],
        [x2 + 1.1, yt + housing_r + 0.1, 0.25],
        0.3,
    );
    b.add_box(
        "motor",
        [x2 + half + 0.1, yt - 0.22, 0.25],
        [x2 + half + 0.75, yt + 0.22, 0.25 + 0.44],
        0.2,
    );

    // The small-bore line along the wall y = W on brackets, down into the floor.
    let small = draw_size(&mut rng, 0, 1);
    let y3 = width - rng.random_range(0.2..0.3);
    let z3 = rng.random_range(1.0..1.4);
    let x3 = rng.random_range(0.35..0.45) * length;
    let bend3 = 1.5 * small.od_m();
    b.add_pipe(
        "small-bore",
        [0.0, y3, z3],
        [x3 - bend3, y3, z3],
        small,
        0.5,
    );
    b.add_elbow(
        [x3 - bend3, y3, z3],
        [1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        small,
    );
    b.add_pipe(
        "small-bore",
        [x3, y3, z3 - bend3],
        [x3, y3, 0.0],
        small,
        0.5,
    );
    for x in [0.3 * x3, 0.7 * x3] {
        b.add_box(
            "support",
            [
                x - 0.03,
                y3 - small.radius() - 0.005,
                z3 - small.radius() - 0.03,
            ],
            [x + 0.03, width, z3 - small.radius()],
            0.3,
        );
    }

    // Conduits under the ceiling, wall to wall along x; a column.
    for k in 0..2 {
        let y = rng.random_range(0.45..0.55) * width + 0.15 * k as f64;
        let z = height - 0.08;
        b.add_round("conduit", [0.0, y, z], [length, y, z], 0.0125, 0.5);
    }
    let cx = rng.random_range(0.8..0.9) * length;
    let cy = rng.random_range(0.7..0.85) * width;
    b.add_box(
        "column",
        [cx - 0.2, cy - 0.2, 0.0],
        [cx + 0.2, cy + 0.2, height],
        0.5,
    );

    b.finish(seed, [length, width, height])
}

/// The scanner stations: 1.5 m above the floor, in the free floor between the equipment.
#[must_use]
pub fn stations(room: &PlantRoom, count: usize) -> Vec<Point3<f64>> {
    let [length, width, _] = room.truth.room;
    let spots = [(0.45, 0.12), (0.75, 0.6), (0.15, 0.6), (0.45, 0.75)];
    spots
        .iter()
        .take(count.clamp(1, spots.len()))
        .map(|(fx, fy)| Point3::new(fx * length, fy * width, 1.5))
        .collect()
}

/// A ray cast: the range and the sub-shape hit, with its outward normal.
fn cast(room: &PlantRoom, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<(f64, usize, f64)> {
    let ray = Ray::new(
        Vector::new(origin.x, origin.y, origin.z),
        Vector::new(dir.x, dir.y, dir.z),
    );
    let (sub, hit) =
        CompositeShapeRef(&room.compound).cast_local_ray_and_get_normal(&ray, 100.0, true)?;
    let cos = -(hit.normal.x * dir.x + hit.normal.y * dir.y + hit.normal.z * dir.z);
    Some((hit.time_of_impact, sub as usize, cos.abs()))
}

/// Scans the room from [`stations`]: a regular azimuth–elevation grid per station, each ray
/// cast through the room's BVH (the first surface hit: shadows and occlusions), range noise
/// along the ray, and a second ray at the edge of the beam's footprint: when it hits a surface
/// at another range (a depth edge), the return blends the two ranges with a random weight (a
/// mixed pixel). Intensity: reflectance × cosine of incidence. Returns the cloud and the
/// count of mixed pixels.
#[must_use]
pub fn scan(room: &PlantRoom, config: &PlantScanConfig, seed: u64) -> (PointCloud, usize) {
    let (cloud, mixed, _) = scan_by_station(room, config, seed);
    (cloud, mixed)
}

/// [`scan`], with how many of the points each station gave (the points are in station order).
#[must_use]
pub fn scan_by_station(
    room: &PlantRoom,
    config: &PlantScanConfig,
    seed: u64,
) -> (PointCloud, usize, Vec<usize>) {
    let mut per_station = Vec::new();
    let (el_lo, el_hi) = config.elevation_range_rad;
    let n_az = (std::f64::consts::TAU / config.step_rad).ceil() as usize;
    let n_el = ((el_hi - el_lo) / config.step_rad).ceil() as usize;
    let mut rows: Vec<(Point3<f64>, f32, bool)> = Vec::new();
    for (s, station) in stations(room, config.stations).iter().enumerate() {
        let part: Vec<Vec<(Point3<f64>, f32, bool)>> = (0..n_el)
            .into_par_iter()
            .map(|i| {
                let mut rng = ChaCha8Rng::seed_from_u64(
                    seed ^ 0x5CA7
                        ^ (s as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                        ^ (i as u64).wrapping_mul(0xD1B5_4A32_D192_ED03),
                );
                let el = el_lo + (i as f64 + 0.5) * (el_hi - el_lo) / n_el as f64;
                (0..n_az)
                    .filter_map(|j| {
                        let az = (j as f64 + 0.5) * config.step_rad;
                        let dir = Vector3::new(az.cos() * el.cos(), az.sin() * el.cos(), el.sin());
                        let (t, sub, cos) = cast(room, station, &dir)?;
                        // The footprint's edge: a random direction at the beam's half-width.
                        let half = 0.5 * (config.beam_diameter_m / t + config.beam_divergence_rad);
                        let phi = rng.random_range(0.0..std::f64::consts::TAU);
                        let (e1, e2) = (
                            Vector3::new(-az.sin(), az.cos(), 0.0),
                            Vector3::new(-el.sin() * az.cos(), -el.sin() * az.sin(), el.cos()),
                        );
                        let edge = (dir + (e1 * phi.cos() + e2 * phi.sin()) * half).normalize();
                        let mut range = t;
                        let mut mixed = false;
                        if let Some((t2, _, _)) = cast(room, station, &edge)
                            && (t2 - t).abs() > 10.0 * config.range_noise_m
                        {
                            let w: f64 = rng.random_range(0.0..1.0);
                            range = w * t + (1.0 - w) * t2;
                            mixed = true;
                        }
                        range += gaussian(&mut rng) * config.range_noise_m;
                        let intensity = room.reflectance[sub] * cos;
                        Some((station + dir * range, intensity as f32, mixed))
                    })
                    .collect()
            })
            .collect();
        let before = rows.len();
        rows.extend(part.into_iter().flatten());
        per_station.push(rows.len() - before);
    }
    let mixed = rows.iter().filter(|r| r.2).count();
    let cloud = PointCloud {
        points: rows.iter().map(|r| r.0).collect(),
        intensity: Some(rows.iter().map(|r| r.1).collect()),
        ..Default::default()
    };
    (cloud, mixed, per_station)
}

/// The heading of station `s`'s own frame about the vertical (rad): a scanner is set up
/// turned any way, and its E57 scan carries that rotation in its pose.
fn station_heading(s: usize) -> f64 {
    (25.0 + 70.0 * s as f64).to_radians()
}

/// Writes the scan as E57 the way a scanner's software exports it: one scan per station, its
/// points (Cartesian, double) in the station's own frame (turned by [`station_heading`]
/// about the vertical, origin at the scanner), its pose (rotation and the station's position)
/// taking them to the room's frame.
fn write_e57(
    path: &std::path::Path,
    cloud: &PointCloud,
    stations: &[Point3<f64>],
    per_station: &[usize],
) -> std::io::Result<()> {
    use e57::{E57Writer, Quaternion, Record, RecordValue, Transform, Translation};
    let io = |e: e57::Error| std::io::Error::other(e.to_string());
    let mut w = E57Writer::from_file(path, "pipemeasure-simulated-plant-room").map_err(io)?;
    let prototype = vec![
        Record::CARTESIAN_X_F64,
        Record::CARTESIAN_Y_F64,
        Record::CARTESIAN_Z_F64,
    ];
    let mut first = 0;
    for (s, (station, &n)) in stations.iter().zip(per_station).enumerate() {
        let heading = station_heading(s);
        let (sin, cos) = heading.sin_cos();
        let (half_sin, half_cos) = (0.5 * heading).sin_cos();
        let mut pc = w
            .add_pointcloud(&format!("station-{}", s + 1), prototype.clone())
            .map_err(io)?;
        pc.set_transform(Some(Transform {
            rotation: Quaternion {
                w: half_cos,
                x: 0.0,
                y: 0.0,
                z: half_sin,
            },
            translation: Translation {
                x: station.x,
                y: station.y,
                z: station.z,
            },
        }));
        for p in &cloud.points[first..first + n] {
            // Room → station: subtract the position, turn by −heading about z.
            let d = p - station;
            pc.add_point(vec![
                RecordValue::Double(cos * d.x + sin * d.y),
                RecordValue::Double(-sin * d.x + cos * d.y),
                RecordValue::Double(d.z),
            ])
            .map_err(io)?;
        }
        pc.finalize().map_err(io)?;
        first += n;
    }
    w.finalize().map_err(io)
}

/// Scans `room` ([`scan_by_station`]) and records the scan in its truth: the cloud, the points
/// each station gave, the truth.
#[must_use]
pub fn scan_into_truth(
    room: PlantRoom,
    config: &PlantScanConfig,
    seed: u64,
) -> (PointCloud, Vec<usize>, PlantTruth) {
    let (cloud, mixed_pixels, per_station) = scan_by_station(&room, config, seed);
    let at: Vec<[f64; 3]> = stations(&room, config.stations)
        .iter()
        .map(|s| [s.x, s.y, s.z])
        .collect();
    let mut truth = room.truth;
    truth.scan = Some(ScanTruth {
        stations: at,
        step_rad: config.step_rad,
        range_noise_m: config.range_noise_m,
        points: cloud.len(),
        mixed_pixels,
    });
    (cloud, per_station, truth)
}

/// `pipemeasure simulate plant`: draws the room of `seed` in `layout`, scans it and writes
/// `OUT/tls_scan.ply` (x, y, z, intensity), with `e57` also `OUT/tls_scan.e57` (one scan per
/// station, with its pose), and `OUT/truth.json` ([`PlantTruth`]), all staged and moved into
/// place together.
///
/// # Errors
///
/// [`WriteError`](crate::io::error::WriteError) naming the file that could not be written.
pub fn simulate_plant(
    layout: PlantLayout,
    seed: u64,
    config: &PlantScanConfig,
    e57: bool,
    out: &std::path::Path,
) -> Result<PlantTruth, crate::io::error::WriteError> {
    std::fs::create_dir_all(out).map_err(|e| crate::io::error::WriteError::new(out, e))?;
    let room = layout.room(seed);
    let placed = stations(&room, config.stations);
    let (cloud, per_station, truth) = scan_into_truth(room, config, seed);
    let ply = crate::io::ply::stage_binary(&out.join("tls_scan.ply"), &cloud)?;
    let e57 = if e57 {
        Some(crate::io::atomic::StagedFile::write_at(
            &out.join("tls_scan.e57"),
            |path| write_e57(path, &cloud, &placed, &per_station),
        )?)
    } else {
        None
    };
    let json = serde_json::to_vec_pretty(&truth).map_err(|e| {
        crate::io::error::WriteError::new(out.join("truth.json"), std::io::Error::other(e))
    })?;
    let truth_file = crate::io::atomic::StagedFile::write(&out.join("truth.json"), |w| {
        std::io::Write::write_all(w, &json)
    })?;
    ply.commit()?;
    if let Some(e57) = e57 {
        e57.commit()?;
    }
    truth_file.commit()?;
    Ok(truth)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ray straight down from above a truth segment's middle hits that segment's top at its
    /// outside radius (the room's shapes are where the truth says).
    #[test]
    fn the_truth_segments_are_where_the_rays_hit() {
        let room = plant_room(3);
        let mut checked = 0;
        for s in &room.truth.segments {
            let (a, b) = (Vector3::from(s.start), Vector3::from(s.end));
            let d = (b - a).normalize();
            if d.z.abs() > 0.5 {
                continue;
            }
            let mid = (a + b) * 0.5;
            let above = Point3::from(mid + Vector3::new(0.0, 0.0, 0.3));
            let (t, sub, cos) = cast(&room, &above, &-Vector3::z()).unwrap();
            if room.parts[sub] != Part::Segment(s.id) {
                continue; // something above it (a conduit, the valve's wheel)
            }
            assert!((t - (0.3 - s.outside_radius_m)).abs() < 1e-9, "{s:?}: {t}");
            assert!((cos - 1.0).abs() < 1e-9);
            checked += 1;
        }
        assert!(checked >= 3, "{checked}");
    }

    /// In both layouts every station is inside the room and inside no shape (a ray from it
    /// leaves it).
    #[test]
    fn the_stations_stand_in_free_space() {
        for seed in 1..6 {
            for room in [PlantLayout::RiserHeader, PlantLayout::Process].map(|l| l.room(seed)) {
                for s in stations(&room, 4) {
                    let [l, w, h] = room.truth.room;
                    assert!(s.x > 0.0 && s.x < l && s.y > 0.0 && s.y < w && s.z < h);
                    for dir in [Vector3::x(), -Vector3::x(), Vector3::y(), -Vector3::y()] {
                        let (t, _, _) = cast(&room, &s, &dir).unwrap();
                        assert!(t > 0.1, "seed {seed} station {s:?}: {t}");
                    }
                }
            }
        }
    }
}
