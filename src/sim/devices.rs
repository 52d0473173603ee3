//! Device presets: plausible 4K-video main cameras of the paper's three phones.
//!
//! The values are invented but shaped like what phone video delivers: principal distance
//! 0.75–0.85 × width, principal point a few to tens of pixels off centre, and small residual
//! radial and decentring distortion (the phones correct most of it in firmware), different for
//! each device. Pixels are square (b1 = b2 = 0).

use crate::camera::{BrownCamera, Intrinsics};

/// Full frame width of the presets (4K UHD video).
pub const PRESET_WIDTH: u32 = 3840;
/// Full frame height of the presets.
pub const PRESET_HEIGHT: u32 = 2160;

/// A simulated phone.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DevicePreset {
    /// Short name used on the command line (`p30`).
    pub name: &'static str,
    /// The phone it imitates.
    pub label: &'static str,
    /// Its true camera at 3840×2160.
    pub camera: BrownCamera,
    /// Rolling-shutter readout time of its 4K video (s): from the middle of the top row's
    /// exposure to the bottom row's (phones read 4K30 out in 15–33 ms).
    pub readout_s: f64,
    /// Focus breathing β (m): with autofocus on, the principal distance follows the focus
    /// distance d as `c(d) = c·(1 + β·(1/d − 1/FOCUS_REFERENCE_M))`. A lens focused at d sits
    /// f·d/(d − f) ≈ f·(1 + f/d) from the sensor (thin lens), so β is about the lens's physical
    /// focal length.
    pub focus_breathing_m: f64,
}

/// Default exposure of the simulated video (s): 1/125 s, a bright indoor scene.
pub const DEFAULT_EXPOSURE_S: f64 = 0.008;
/// Focus distance at which a preset's principal distance is its nominal `c` (m): about the
/// lab's and the site's viewing distance.
pub const FOCUS_REFERENCE_M: f64 = 2.5;

/// The factor multiplying c (and b1, b2) when a camera of focus breathing `beta_m` is focused
/// at `distance_m` ([`DevicePreset::focus_breathing_m`]).
#[must_use]
pub fn breathing_factor(beta_m: f64, distance_m: f64) -> f64 {
    1.0 + beta_m * (1.0 / distance_m - 1.0 / FOCUS_REFERENCE_M)
}

/// Huawei P30: moderate barrel-to-pincushion residual (k1, k2) and decentring.
pub const P30: DevicePreset = DevicePreset {
    name: "p30",
    label: "Huawei P30 (simulated)",
    camera: BrownCamera {
        width: PRESET_WIDTH,
        height: PRESET_HEIGHT,
        intrinsics: Intrinsics {
            c: 3050.0,
            u0: 1931.4,
            v0: 1074.6,
            k1: 0.0125,
            k2: -0.0094,
            k3: 0.0,
            p1: 1.6e-4,
            p2: -2.1e-4,
            b1: 0.0,
            b2: 0.0,
        },
    },
    readout_s: 0.020,
    // Main camera 5.56 mm (27 mm equivalent).
    focus_breathing_m: 0.0056,
};

/// iPhone 11: wider lens, opposite-sign radial residual and very small decentring.
pub const IPHONE11: DevicePreset = DevicePreset {
    name: "iphone11",
    label: "Apple iPhone 11 (simulated)",
    camera: BrownCamera {
        width: PRESET_WIDTH,
        height: PRESET_HEIGHT,
        intrinsics: Intrinsics {
            c: 2950.0,
            u0: 1908.2,
            v0: 1089.7,
            k1: -0.0185,
            k2: 0.0105,
            k3: 0.0,
            p1: -6.0e-5,
            p2: 4.0e-5,
            b1: 0.0,
            b2: 0.0,
        },
    },
    readout_s: 0.025,
    // Main camera 4.25 mm (26 mm equivalent).
    focus_breathing_m: 0.00425,
};

/// Samsung S10: longer principal distance and a third radial term.
pub const S10: DevicePreset = DevicePreset {
    name: "s10",
    label: "Samsung Galaxy S10 (simulated)",
    camera: BrownCamera {
        width: PRESET_WIDTH,
        height: PRESET_HEIGHT,
        intrinsics: Intrinsics {
            c: 3180.0,
            u0: 1944.0,
            v0: 1061.5,
            k1: 0.021,
            k2: -0.032,
            k3: 0.018,
            p1: -3.0e-4,
            p2: 1.2e-4,
            b1: 0.0,
            b2: 0.0,
        },
    },
    readout_s: 0.030,
    // Main camera 4.3 mm (26 mm equivalent).
    focus_breathing_m: 0.0043,
};

/// Every preset.
pub const PRESETS: [DevicePreset; 3] = [P30, IPHONE11, S10];

/// The preset called `name`.
#[must_use]
pub fn preset(name: &str) -> Option<DevicePreset> {
    PRESETS.into_iter().find(|p| p.name == name)
}

/// A preset's camera at another frame size of the same aspect ratio (intrinsics scale with the
/// width; the normalised distortion does not change).
#[must_use]
pub fn preset_camera(p: &DevicePreset, width: u32, height: u32) -> BrownCamera {
    p.camera.scaled(width, height)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_plausible_phone_cameras() {
        for p in PRESETS {
            let i = p.camera.intrinsics;
            let ratio = i.c / f64::from(PRESET_WIDTH);
            assert!(
                (0.75..=0.85).contains(&ratio),
                "{}: c/width = {ratio}",
                p.name
            );
            let du = (i.u0 - 1920.0).abs();
            let dv = (i.v0 - 1080.0).abs();
            assert!(
                (2.0..=40.0).contains(&du) && (2.0..=40.0).contains(&dv),
                "{}",
                p.name
            );
            // Residual distortion is small but real: at the corner it moves the point by
            // between 1 and 40 px.
            let corner = i
                .ideal_from_pixel(&nalgebra::Vector2::new(0.0, 0.0))
                .unwrap();
            let pinhole = nalgebra::Vector2::new(i.c * corner.x + i.u0, i.c * corner.y + i.v0);
            let shift = pinhole.norm();
            assert!(
                (1.0..=40.0).contains(&shift),
                "{}: corner shift {shift} px",
                p.name
            );
        }
        assert_ne!(P30.camera, S10.camera);
        // Readout 20–30 ms (the video labs); breathing of a 4–6 mm lens: focusing from
        // 2.5 m to 1 m lengthens c by 0.26–0.34 %.
        assert_eq!(PRESETS.map(|p| p.readout_s), [0.020, 0.025, 0.030]);
        for p in PRESETS {
            let f = breathing_factor(p.focus_breathing_m, 1.0);
            assert!((1.0025..=1.0035).contains(&f), "{}: {f}", p.name);
        }
        assert_eq!(breathing_factor(0.005, FOCUS_REFERENCE_M), 1.0);
        assert_eq!(preset("s10"), Some(S10));
        assert_eq!(preset("nokia"), None);
    }
}
