//! Renders the small example frames used by the README's first command
//! (`examples/frames/*.jpg`) and their device profile (`examples/p30-960x540.json`): a wall
//! with a grid of lines and circular targets seen by the p30 preset scaled to 960×540, with the
//! lens distortion applied exactly per pixel (each pixel centre is undistorted to its ray), so
//! that `pipemeasure undistort` visibly straightens the lines.
//!
//! `cargo run --release --example example_frames`

use std::collections::BTreeMap;
use std::path::Path;

use image::{ImageBuffer, Rgb};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use pipemeasure::profile::Profile;
use pipemeasure::sim::devices::{P30, preset_camera};

/// Grey level of the wall at a point of its plane (metres): white with black lines every
/// 0.25 m and black discs of radius 0.05 m at the cell centres.
fn wall(x: f64, y: f64) -> f64 {
    let cell = 0.25;
    let (fx, fy) = ((x / cell).rem_euclid(1.0), (y / cell).rem_euclid(1.0));
    let line = 0.006 / cell;
    if fx < line || fy < line {
        return 30.0;
    }
    let (dx, dy) = ((fx - 0.5) * cell, (fy - 0.5) * cell);
    if dx * dx + dy * dy < 0.05 * 0.05 {
        25.0
    } else {
        225.0
    }
}

fn main() -> anyhow::Result<()> {
    let cam = preset_camera(&P30, 960, 540);
    let out = Path::new("examples/frames");
    std::fs::create_dir_all(out)?;
    let views = [(0.0, 0.0, 0.0), (0.15, -0.2, 0.05), (-0.2, 0.1, -0.1)];
    for (k, (yaw, pitch, roll)) in views.into_iter().enumerate() {
        // The wall is the plane z = 0 of the world, the camera 2 m in front of it.
        let world_from_cam = Isometry3::from_parts(
            Translation3::new(0.1, -0.05, -2.0),
            UnitQuaternion::from_euler_angles(pitch, yaw, roll),
        );
        let img = ImageBuffer::from_fn(cam.width, cam.height, |col, row| {
            // 3×3 samples per pixel.
            let mut sum = 0.0;
            for sy in 0..3 {
                for sx in 0..3 {
                    let uv = Vector2::new(
                        f64::from(col) + (f64::from(sx) + 0.5) / 3.0,
                        f64::from(row) + (f64::from(sy) + 0.5) / 3.0,
                    );
                    let Ok(xy) = cam.intrinsics.ideal_from_pixel(&uv) else {
                        continue;
                    };
                    let origin = world_from_cam * Point3::origin();
                    let dir = world_from_cam.rotation * Vector3::new(xy.x, xy.y, 1.0);
                    let t = -origin.z / dir.z;
                    let p = origin + dir * t;
                    sum += wall(p.x, p.y);
                }
            }
            let v = (sum / 9.0).round() as u8;
            Rgb([v, v, v.saturating_sub(8)])
        });
        let path = out.join(format!("frame_{:04}.jpg", k + 1));
        img.save(&path)?;
        println!("wrote {}", path.display());
    }
    let provenance = BTreeMap::from([
        ("source".to_string(), "nominal".into()),
        (
            "note".to_string(),
            "p30 preset scaled to 960x540 for the README example".into(),
        ),
        (
            "command".to_string(),
            "cargo run --release --example example_frames".into(),
        ),
    ]);
    let profile = Profile::uncalibrated("p30-960x540", &cam, provenance);
    let path = Path::new("examples/p30-960x540.json");
    profile.write(path, true)?;
    println!("wrote {}", path.display());
    Ok(())
}
