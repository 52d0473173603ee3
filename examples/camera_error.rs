//! The error of a calibrated profile against a simulated lab's true camera, over the frame:
//! `cargo run --release --example camera_error -- PROFILE.json LAB/truth.json`. Prints the
//! projection difference (px, max and RMS over a grid of the frame, as it is and after the
//! best rotation between the two cameras), the profile's projection σ (max, RMS), their ratio,
//! and the readout time against the truth's when both have one.
#![allow(missing_docs)]

use std::path::PathBuf;

use pipemeasure::calibrate::checks::{
    projection_difference, projection_difference_rotated, projection_uncertainty,
};
use pipemeasure::profile::Profile;
use pipemeasure::sim::truth::Truth;

fn main() -> anyhow::Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [profile, truth] = args.as_slice() else {
        anyhow::bail!("usage: camera_error PROFILE.json truth.json");
    };
    let profile = Profile::read(profile)?;
    let truth = Truth::read(truth)?;
    let size = (truth.camera.width, truth.camera.height);
    let est = profile.intrinsics;
    let tru = truth.camera.intrinsics;
    let diff = projection_difference(&est, &tru, size);
    let rotated = projection_difference_rotated(&est, &tru, size);
    let sigma = projection_uncertainty(&est, &profile.covariance(), size);
    println!(
        "camera vs truth: max {:.4} px, RMS {:.4} px; after the best rotation ({:.4}°) max {:.4} px, RMS {:.4} px",
        diff.max, diff.rms, rotated.rotation_deg, rotated.map.max, rotated.map.rms
    );
    println!(
        "projection σ: max {:.4} px, RMS {:.4} px; error / σ: max over the frame {:.2}",
        sigma.max,
        sigma.rms,
        diff.max_ratio_to(&sigma)
    );
    println!(
        "c {:.3} (true {:.3}), u0 {:.3} ({:.3}), v0 {:.3} ({:.3})",
        est.c, tru.c, est.u0, tru.u0, est.v0, tru.v0
    );
    let true_readout = truth.video.as_ref().map(|v| v.readout_s);
    if let Some(r) = &profile.rolling_shutter {
        println!(
            "readout {:.3} ± {:.3} ms ({}), true {}",
            1e3 * r.readout_s,
            1e3 * r.readout_std_s,
            if r.estimated { "estimated" } else { "held" },
            true_readout.map_or("-".into(), |t| format!("{:.3} ms", 1e3 * t))
        );
    }
    Ok(())
}
