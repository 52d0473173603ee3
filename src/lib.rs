//! pipemeasure turns phone video into metric measurements of mechanical pipes.
//!
//! It implements Maalek & Lichti, "Automated calibration of mobile cameras for 3D reconstruction of
//! mechanical pipes" (`../shared/paper.md`), with two jobs:
//!
//! * **calibrate** a phone once per device from a video of a lab corner covered with circular
//!   targets, producing a device profile (`NAME.json` in a profile folder, [`profile::Profile`]);
//! * **measure** a pipe on site: undistort the frames with the profile, scale the dense cloud
//!   from targets against TLS coordinates, and fit a robust cylinder.
//!
//! # Conventions
//!
//! * **Pixels** `uv = (u, v)`: u right, v down, origin at the top-left *corner* of the image, so the
//!   centre of the top-left pixel is `(0.5, 0.5)` (COLMAP's convention). OpenCV puts `(0, 0)` at
//!   the centre of that pixel: `cx_opencv = u0 − 0.5`.
//! * **Camera frame**: X right, Y down, Z forward. A pose is named for what it maps:
//!   `cam_from_world` maps world points into the camera frame, `p_cam = R·p_world + t`, which is
//!   what COLMAP stores (quaternion `qw, qx, qy, qz` and translation).
//! * **Normalised coordinates**: `xy = (X/Z, Y/Z)` are ideal (undistorted), `xy_d` distorted.
//! * **Camera model `brown`** ([`camera::Intrinsics`]): OpenCV's k1, k2, p1, p2, k3 model plus
//!   affinity b1 and shear b2: `u = (c + b1)·xd + b2·yd + u0`, `v = c·yd + v0`.
//! * **Units**: metres and radians, unsuffixed; pixels carry `_px`. `f64` everywhere in geometry.
//! * **Conics** are normalised to unit Frobenius norm with the interior negative.
//! * **Randomness** always takes a seed; the same input and seed give the same output whatever the
//!   number of threads.
//!
//! # Quick start
//!
//! ```
//! use nalgebra::Vector3;
//! use pipemeasure::camera::Intrinsics;
//!
//! let cam = Intrinsics { k1: 0.01, ..Intrinsics::pinhole(3000.0, 1920.0, 1080.0) };
//! let uv = cam.project(&Vector3::new(0.3, -0.2, 2.0)).expect("in front of the camera");
//! let xy = cam.ideal_from_pixel(&uv).expect("inside the valid region");
//! assert!((xy.x - 0.15).abs() < 1e-12 && (xy.y + 0.1).abs() < 1e-12);
//! ```

pub mod adjust;
pub mod calibrate;
pub mod camera;
pub mod detect;
pub mod experiments;
pub mod geometry;
pub mod io;
pub mod measure;
pub mod profile;
pub mod report;
pub mod robust;
pub mod sim;
pub mod video;
