//! Scene geometry for the simulator: textured rectangles (walls, floor) carrying circular
//! targets on square plates, textured open cylinders (pipes), point lights. Rays are
//! intersected analytically; shading is Lambertian with inverse-square fall-off plus ambient
//! light (no shadows).

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::texture::Texture;

/// Albedo of the black print of a target (matte).
pub const BLACK_ALBEDO: f64 = 0.04;
/// Albedo of the white print of a target (matte paper).
pub const WHITE_ALBEDO: f64 = 0.88;
/// Radiance of rays that hit nothing (the room beyond the modelled surfaces).
pub const BACKGROUND_RADIANCE: f64 = 0.22;

/// Which colour the disc of a target is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// A black disc on a white square plate.
    BlackOnWhite,
    /// A white disc on a black square plate.
    WhiteOnBlack,
}

impl Polarity {
    /// (disc albedo, plate albedo).
    #[must_use]
    pub fn albedos(self) -> (f64, f64) {
        match self {
            Polarity::BlackOnWhite => (BLACK_ALBEDO, WHITE_ALBEDO),
            Polarity::WhiteOnBlack => (WHITE_ALBEDO, BLACK_ALBEDO),
        }
    }
}

/// A circular target printed on a square plate lying on a surface.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Target {
    /// Target id (1-based, unique in the scene).
    pub id: u32,
    /// Centre of the disc (world, m).
    pub centre: [f64; 3],
    /// Unit normal, pointing away from the wall into the room.
    pub normal: [f64; 3],
    /// Disc radius (m).
    pub radius: f64,
    /// Half the side of the square plate (m).
    pub plate_half: f64,
    /// Colours.
    pub polarity: Polarity,
}

/// A textured rectangle `origin + a·u + b·v`, `a ∈ [0, size.0]`, `b ∈ [0, size.1]`.
#[derive(Clone, Debug)]
pub struct Rect {
    /// Name for truth files (`wall_a`, `floor`, ...).
    pub name: String,
    origin: Point3<f64>,
    u: Vector3<f64>,
    v: Vector3<f64>,
    normal: Vector3<f64>,
    size: (f64, f64),
    texture: Texture,
    decals: Decals,
}

impl Rect {
    /// A rectangle with orthonormal in-plane axes `u`, `v` (normal `u × v` faces the room).
    #[must_use]
    pub fn new(
        name: &str,
        origin: Point3<f64>,
        u: Vector3<f64>,
        v: Vector3<f64>,
        size: (f64, f64),
        texture: Texture,
    ) -> Self {
        let (u, v) = (u.normalize(), v.normalize());
        Rect {
            name: name.into(),
            origin,
            u,
            v,
            normal: u.cross(&v).normalize(),
            size,
            texture,
            decals: Decals::default(),
        }
    }

    /// Size (m).
    #[must_use]
    pub fn size(&self) -> (f64, f64) {
        self.size
    }

    /// The world point at plane coordinates (a, b).
    #[must_use]
    pub fn point(&self, a: f64, b: f64) -> Point3<f64> {
        self.origin + self.u * a + self.v * b
    }

    /// The facing normal.
    #[must_use]
    pub fn normal(&self) -> Vector3<f64> {
        self.normal
    }

    /// In-plane axes (u, v).
    #[must_use]
    pub fn axes(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.u, self.v)
    }
}

/// Targets on a rectangle, bucketed on a grid of its plane coordinates.
#[derive(Clone, Debug, Default)]
struct Decals {
    cell: f64,
    cols: usize,
    rows: usize,
    /// Per cell: indices into `items`.
    cells: Vec<Vec<u32>>,
    /// (a, b, plate_half, radius², target index, polarity).
    items: Vec<(f64, f64, f64, f64, u32, Polarity)>,
}

impl Decals {
    fn build(&mut self, size: (f64, f64), items: Vec<(f64, f64, f64, f64, u32, Polarity)>) {
        let largest = items.iter().map(|i| i.2).fold(0.0f64, f64::max);
        self.cell = (2.0 * largest).max(0.05);
        self.cols = (size.0 / self.cell).ceil() as usize + 1;
        self.rows = (size.1 / self.cell).ceil() as usize + 1;
        self.cells = vec![Vec::new(); self.cols * self.rows];
        for (k, it) in items.iter().enumerate() {
            let (c0, c1) = (self.col(it.0 - it.2), self.col(it.0 + it.2));
            let (r0, r1) = (self.row(it.1 - it.2), self.row(it.1 + it.2));
            for r in r0..=r1 {
                for c in c0..=c1 {
                    self.cells[r * self.cols + c].push(k as u32);
                }
            }
        }
        self.items = items;
    }

    fn col(&self, a: f64) -> usize {
        ((a / self.cell).max(0.0) as usize).min(self.cols - 1)
    }

    fn row(&self, b: f64) -> usize {
        ((b / self.cell).max(0.0) as usize).min(self.rows - 1)
    }

    /// (albedo, target index, zone: 1 plate, 2 disc) at (a, b), if on a target.
    fn at(&self, a: f64, b: f64) -> Option<(f64, u32, u64)> {
        if self.items.is_empty() {
            return None;
        }
        for &k in &self.cells[self.row(b) * self.cols + self.col(a)] {
            let (ca, cb, half, r2, index, polarity) = self.items[k as usize];
            let (da, db) = (a - ca, b - cb);
            if da.abs() <= half && db.abs() <= half {
                let (disc, plate) = polarity.albedos();
                return Some(if da * da + db * db <= r2 {
                    (disc, index, 2)
                } else {
                    (plate, index, 1)
                });
            }
        }
        None
    }
}

/// An open textured cylinder (a pipe): axis from `start` along unit `dir` for `length`.
#[derive(Clone, Debug)]
pub struct Cylinder {
    /// Name for truth files.
    pub name: String,
    start: Point3<f64>,
    dir: Vector3<f64>,
    length: f64,
    radius: f64,
    texture: Texture,
    /// A unit vector ⊥ dir fixing angle 0 of the texture.
    ref_dir: Vector3<f64>,
}

impl Cylinder {
    /// A pipe of `radius` along `dir` from `start` for `length`.
    #[must_use]
    pub fn new(
        name: &str,
        start: Point3<f64>,
        dir: Vector3<f64>,
        length: f64,
        radius: f64,
        texture: Texture,
    ) -> Self {
        let dir = dir.normalize();
        let ref_dir = crate::geometry::plane_basis(&dir).0;
        Cylinder {
            name: name.into(),
            start,
            dir,
            length,
            radius,
            texture,
            ref_dir,
        }
    }

    /// Axis start, direction, length and radius.
    #[must_use]
    pub fn geometry(&self) -> (Point3<f64>, Vector3<f64>, f64, f64) {
        (self.start, self.dir, self.length, self.radius)
    }

    /// The surface point at angle `phi` and axial position `s`, and its outward normal.
    #[must_use]
    pub fn surface(&self, phi: f64, s: f64) -> (Point3<f64>, Vector3<f64>) {
        let other = self.dir.cross(&self.ref_dir);
        let n = self.ref_dir * phi.cos() + other * phi.sin();
        (self.start + self.dir * s + n * self.radius, n)
    }
}

/// A point light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Position (world, m).
    pub position: Point3<f64>,
    /// Intensity: irradiance at 1 m on a surface facing the light.
    pub intensity: f64,
}

/// What a ray hits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit (`origin + t·dir`).
    pub t: f64,
    /// Unit normal of the surface at the hit, facing the ray's origin.
    pub normal: Vector3<f64>,
    /// Albedo.
    pub albedo: f64,
    /// Region id: equal ids mean the same smooth piece of surface (same surface, same target
    /// zone), so a pixel whose probes share one id has no edge inside it.
    pub region: u64,
}

/// A scene: surfaces, targets and lights.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// Rectangles.
    pub rects: Vec<Rect>,
    /// Pipes.
    pub cylinders: Vec<Cylinder>,
    /// Targets (also registered as decals on their rectangle).
    pub targets: Vec<Target>,
    /// Lights.
    pub lights: Vec<Light>,
    /// Ambient irradiance.
    pub ambient: f64,
    /// Solids of any shape (a plant room's parry3d compound), hit after the rectangles and
    /// cylinders with their own albedo.
    pub solids: Option<std::sync::Arc<Solids>>,
}

/// Solids of any shape for the camera's scene: a parry3d compound (one bounding-volume
/// hierarchy over its sub-shapes) and each sub-shape's albedo. A plant room
/// ([`super::plant`]) is rendered, observed and occludes through it.
pub struct Solids {
    /// The shapes.
    pub compound: parry3d_f64::shape::Compound,
    /// Per sub-shape, its albedo.
    pub albedo: Vec<f64>,
}

impl std::fmt::Debug for Solids {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Solids")
            .field("shapes", &self.compound.shapes().len())
            .finish_non_exhaustive()
    }
}

impl Solids {
    /// The nearest hit of `origin + t·dir` with `T_MIN < t < max_t`: `(t, sub-shape, outward
    /// normal)`.
    fn cast(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        max_t: f64,
    ) -> Option<(f64, usize, Vector3<f64>)> {
        use parry3d_f64::math::Vector;
        use parry3d_f64::query::Ray;
        use parry3d_f64::shape::CompositeShapeRef;
        // Start just past T_MIN so a ray leaving a solid's surface does not hit it again.
        let start = origin + dir * T_MIN;
        let ray = Ray::new(
            Vector::new(start.x, start.y, start.z),
            Vector::new(dir.x, dir.y, dir.z),
        );
        let limit = if max_t.is_finite() { max_t } else { 1e6 };
        let (sub, hit) = CompositeShapeRef(&self.compound).cast_local_ray_and_get_normal(
            &ray,
            limit - T_MIN,
            true,
        )?;
        let n = Vector3::new(hit.normal.x, hit.normal.y, hit.normal.z);
        (hit.time_of_impact > 0.0).then_some((hit.time_of_impact + T_MIN, sub as usize, n))
    }
}

/// Rays closer than this (m) to their origin are ignored (self-intersection guard).
const T_MIN: f64 = 1e-9;

impl Scene {
    /// Places targets on rectangle `rect` at plane coordinates; `targets[k]` lies at
    /// `coords[k]`. The targets are appended to the scene's list.
    ///
    /// # Panics
    ///
    /// If `rect` is out of range (a programming error of the scene builders).
    pub fn place_targets(&mut self, rect: usize, placed: Vec<(f64, f64, f64, f64, Polarity)>) {
        let mut items = Vec::with_capacity(placed.len());
        for (a, b, radius, plate_half, polarity) in placed {
            let index = self.targets.len() as u32;
            let r = &self.rects[rect];
            let c = r.point(a, b);
            self.targets.push(Target {
                id: index + 1,
                centre: [c.x, c.y, c.z],
                normal: [r.normal.x, r.normal.y, r.normal.z],
                radius,
                plate_half,
                polarity,
            });
            items.push((a, b, plate_half, radius * radius, index, polarity));
        }
        let size = self.rects[rect].size;
        let mut existing = std::mem::take(&mut self.rects[rect].decals.items);
        existing.extend(items);
        self.rects[rect].decals.build(size, existing);
    }

    /// The nearest hit of the ray `origin + t·dir`, `t > 0` (`dir` need not be unit).
    #[must_use]
    pub fn intersect(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        // Find the nearest surface first; shade (texture, decals) only that one.
        enum Nearest {
            None,
            Rect {
                k: usize,
                a: f64,
                b: f64,
                front: bool,
            },
            Cylinder {
                k: usize,
                normal: Vector3<f64>,
                s: f64,
                phi: f64,
            },
        }
        let mut best_t = f64::INFINITY;
        let mut nearest = Nearest::None;
        for (k, r) in self.rects.iter().enumerate() {
            let denom = dir.dot(&r.normal);
            if denom.abs() < 1e-15 {
                continue;
            }
            let t = (r.origin - origin).dot(&r.normal) / denom;
            if t <= T_MIN || t >= best_t {
                continue;
            }
            let d = origin + dir * t - r.origin;
            let (a, b) = (d.dot(&r.u), d.dot(&r.v));
            if a < 0.0 || b < 0.0 || a > r.size.0 || b > r.size.1 {
                continue;
            }
            best_t = t;
            nearest = Nearest::Rect {
                k,
                a,
                b,
                front: denom < 0.0,
            };
        }
        for (k, c) in self.cylinders.iter().enumerate() {
            let Some((t, normal, s, phi)) = intersect_cylinder(c, origin, dir) else {
                continue;
            };
            if t < best_t {
                best_t = t;
                nearest = Nearest::Cylinder { k, normal, s, phi };
            }
        }
        if let Some(solids) = &self.solids
            && let Some((t, sub, n)) = solids.cast(origin, dir, best_t)
            && t < best_t
        {
            let normal = if n.dot(dir) < 0.0 { n } else { -n };
            let region =
                (self.rects.len() as u64 + self.cylinders.len() as u64 + sub as u64 + 1) << 40;
            return Some(Hit {
                t,
                normal,
                albedo: solids.albedo.get(sub).copied().unwrap_or(0.5),
                region,
            });
        }
        match nearest {
            Nearest::None => None,
            Nearest::Rect { k, a, b, front } => {
                let r = &self.rects[k];
                let normal = if front { r.normal } else { -r.normal };
                let surface = (k as u64 + 1) << 40;
                Some(match r.decals.at(a, b) {
                    Some((albedo, index, zone)) => Hit {
                        t: best_t,
                        normal,
                        albedo,
                        region: surface | (u64::from(index) + 1) << 4 | zone,
                    },
                    None => Hit {
                        t: best_t,
                        normal,
                        albedo: r.texture.albedo(a, b),
                        region: surface,
                    },
                })
            }
            Nearest::Cylinder { k, normal, s, phi } => {
                let c = &self.cylinders[k];
                let region = (self.rects.len() as u64 + k as u64 + 1) << 40;
                Some(Hit {
                    t: best_t,
                    normal,
                    albedo: c.texture.albedo(phi * c.radius, s),
                    region,
                })
            }
        }
    }

    /// Radiance seen along a ray and the region id (0 for the background).
    #[must_use]
    pub fn radiance(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> (f64, u64) {
        let Some(hit) = self.intersect(origin, dir) else {
            return (BACKGROUND_RADIANCE, 0);
        };
        let p = origin + dir * hit.t;
        (hit.albedo * self.irradiance(&p, &hit.normal), hit.region)
    }

    /// Irradiance at a point with unit normal `n`.
    #[must_use]
    pub fn irradiance(&self, p: &Point3<f64>, n: &Vector3<f64>) -> f64 {
        let mut e = self.ambient;
        for l in &self.lights {
            let d = l.position - p;
            let d2 = d.norm_squared();
            let cos = n.dot(&d) / d2.sqrt();
            if cos > 0.0 {
                e += l.intensity * cos / d2;
            }
        }
        e
    }

    /// Whether the segment from `from` to `to` is free of surfaces (ignoring a hit within
    /// `tolerance_m` of `to`, e.g. the surface `to` lies on).
    #[must_use]
    pub fn visible(&self, from: &Point3<f64>, to: &Point3<f64>, tolerance_m: f64) -> bool {
        let dir = to - from;
        let len = dir.norm();
        match self.intersect(from, &dir) {
            Some(h) => h.t * len >= len - tolerance_m,
            None => true,
        }
    }
}

/// Ray–cylinder intersection on the outside of the open cylinder: (t, normal facing the ray,
/// axial position, angle).
fn intersect_cylinder(
    c: &Cylinder,
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
) -> Option<(f64, Vector3<f64>, f64, f64)> {
    let w = origin - c.start;
    let dp = dir - c.dir * dir.dot(&c.dir);
    let wp = w - c.dir * w.dot(&c.dir);
    let a = dp.norm_squared();
    if a < 1e-300 {
        return None;
    }
    let b = 2.0 * dp.dot(&wp);
    let cc = wp.norm_squared() - c.radius * c.radius;
    let disc = b * b - 4.0 * a * cc;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // Numerically stable roots.
    let q = -0.5 * (b + b.signum() * sq);
    let (mut t0, mut t1) = (q / a, cc / q);
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    for t in [t0, t1] {
        if t <= T_MIN || !t.is_finite() {
            continue;
        }
        let p = origin + dir * t;
        let s = (p - c.start).dot(&c.dir);
        if s < 0.0 || s > c.length {
            continue;
        }
        let radial = (p - c.start) - c.dir * s;
        let n = radial / c.radius;
        let normal = if n.dot(dir) < 0.0 { n } else { -n };
        let other = c.dir.cross(&c.ref_dir);
        let phi = n
            .dot(&other)
            .atan2(n.dot(&c.ref_dir))
            .rem_euclid(std::f64::consts::TAU);
        return Some((t, normal, s, phi));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall_scene() -> Scene {
        let mut s = Scene {
            rects: vec![Rect::new(
                "wall",
                Point3::new(-1.0, 0.0, 0.0),
                Vector3::x(),
                Vector3::z(),
                (2.0, 2.0),
                Texture::constant(0.5),
            )],
            ambient: 1.0,
            ..Default::default()
        };
        s.place_targets(0, vec![(1.0, 1.0, 0.02, 0.05, Polarity::BlackOnWhite)]);
        s
    }

    #[test]
    fn rays_hit_wall_plate_and_disc() {
        let s = wall_scene();
        // Wall plane y = 0 with normal x × z = −y: the room is at y < 0.
        assert_eq!(s.rects[0].normal(), Vector3::new(0.0, -1.0, 0.0));
        let o = Point3::new(0.0, -2.0, 1.0);
        let disc = s.intersect(&o, &Vector3::new(0.0, 1.0, 0.0)).unwrap();
        assert!(
            (disc.t - 2.0).abs() < 1e-12 && disc.albedo == BLACK_ALBEDO && disc.region & 0xf == 2
        );
        let plate = s.intersect(&o, &Vector3::new(0.03, 2.0, 0.0)).unwrap();
        assert!(plate.albedo == WHITE_ALBEDO && plate.region & 0xf == 1);
        let wall = s.intersect(&o, &Vector3::new(0.2, 1.0, 0.0)).unwrap();
        assert!(wall.albedo == 0.5 && wall.region == 1 << 40);
        assert!(s.intersect(&o, &Vector3::new(0.0, -1.0, 0.0)).is_none());
        assert_eq!(s.targets[0].centre, [0.0, 0.0, 1.0]);
    }

    #[test]
    fn cylinder_hits_the_near_side_and_occludes() {
        let mut s = wall_scene();
        s.cylinders.push(Cylinder::new(
            "pipe",
            Point3::new(-1.0, -0.5, 1.2),
            Vector3::x(),
            2.0,
            0.1,
            Texture::constant(0.6),
        ));
        let o = Point3::new(0.0, -2.0, 1.2);
        let h = s.intersect(&o, &Vector3::new(0.0, 1.0, 0.0)).unwrap();
        assert!((h.t - 1.4).abs() < 1e-12, "{}", h.t);
        assert!((h.normal - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
        assert!(!s.visible(&o, &Point3::new(0.0, 0.0, 1.2), 1e-6));
        assert!(s.visible(&o, &Point3::new(0.0, 0.0, 1.0), 1e-6));
        let (p, n) = s.cylinders[0].surface(1.0, 0.5);
        let radial = p - Point3::new(-0.5, -0.5, 1.2);
        assert!((radial.norm() - 0.1).abs() < 1e-12 && (radial / 0.1 - n).norm() < 1e-12);
    }

    #[test]
    fn irradiance_falls_off_with_distance_squared() {
        let mut s = wall_scene();
        s.ambient = 0.0;
        s.lights.push(Light {
            position: Point3::new(0.0, -2.0, 1.0),
            intensity: 4.0,
        });
        let e = s.irradiance(&Point3::new(0.0, 0.0, 1.0), &Vector3::new(0.0, -1.0, 0.0));
        assert!((e - 1.0).abs() < 1e-12);
    }
}
