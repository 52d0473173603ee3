//! Helpers shared by integration tests.
#![allow(dead_code, clippy::unwrap_used)]

use image::{ImageBuffer, Luma};
use nalgebra::Vector2;
use pipemeasure::camera::BrownCamera;

/// The repository's device profiles, for `PIPEMEASURE_CALIBRATIONS`.
pub const CALIBRATIONS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/calibrations");

/// Renders a frame of `cam` by point-sampling `f` at the ideal normalised coordinates of every
/// pixel centre (exact lens distortion, no image warp). `f` returns 16-bit grey levels.
pub fn render_distorted(
    cam: &BrownCamera,
    f: impl Fn(&Vector2<f64>) -> f64 + Sync,
) -> ImageBuffer<Luma<u16>, Vec<u16>> {
    use rayon::prelude::*;
    let w = cam.width as usize;
    let mut data = vec![0u16; w * cam.height as usize];
    data.par_chunks_mut(w).enumerate().for_each(|(row, line)| {
        for (col, px) in line.iter_mut().enumerate() {
            let uv = Vector2::new(col as f64 + 0.5, row as f64 + 0.5);
            let xy = cam.intrinsics.ideal_from_pixel(&uv).unwrap();
            *px = f(&xy).round().clamp(0.0, 65535.0) as u16;
        }
    });
    ImageBuffer::from_raw(cam.width, cam.height, data).unwrap()
}

/// A user data folder no test writes to: [`pipemeasure`] points `XDG_DATA_HOME` at it, so no
/// run sees the profiles of the user running the tests.
pub fn no_user_data() -> std::path::PathBuf {
    std::env::temp_dir().join("pipemeasure-tests-no-user-data")
}

/// Runs the pipemeasure binary with `args` in `cwd`, returning (exit code, stdout, stderr);
/// `$PIPEMEASURE_CALIBRATIONS` unset and the user data folder [`no_user_data`] unless `env`
/// sets them.
pub fn pipemeasure(
    cwd: &std::path::Path,
    args: &[&str],
    env: &[(&str, &str)],
) -> (i32, String, String) {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_pipemeasure"));
    cmd.current_dir(cwd)
        .args(args)
        .env_remove("PIPEMEASURE_CALIBRATIONS")
        .env("XDG_DATA_HOME", no_user_data());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// [`pipemeasure`] with the repository's device profiles ([`CALIBRATIONS`]).
pub fn pipemeasure_with_profiles(dir: &std::path::Path, args: &[&str]) -> (i32, String, String) {
    pipemeasure(dir, args, &[("PIPEMEASURE_CALIBRATIONS", CALIBRATIONS)])
}

/// Whether `program ARG` runs; under CI (`CI=true`) its absence is a failure, not a skip (the
/// CI script installs it with `install`).
pub fn program_available(program: &str, arg: &str, install: &str) -> bool {
    let found = std::process::Command::new(program)
        .arg(arg)
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        assert!(
            std::env::var("CI").map(|v| v != "true").unwrap_or(true),
            "CI=true but `{program}` is not on PATH: .ci/run must install it ({install})"
        );
        eprintln!("skipping: {program} is not installed ({install})");
    }
    found
}

/// [`program_available`] for COLMAP.
pub fn colmap_available() -> bool {
    program_available("colmap", "help", "apt-get install -y colmap")
}

/// Runs `pipemeasure simulate SCENE… --out OUT --quiet` in `dir`, asserts that it succeeded and
/// returns the scene's folder (`dir/OUT`).
pub fn simulate(dir: &std::path::Path, out: &str, scene: &[&str]) -> std::path::PathBuf {
    let mut args = vec!["simulate"];
    args.extend_from_slice(scene);
    args.extend_from_slice(&["--out", out, "--quiet"]);
    let (code, _, stderr) = pipemeasure(dir, &args, &[]);
    assert_eq!(code, 0, "simulate {scene:?}: {stderr}");
    dir.join(out)
}

/// [`simulate`] of a lab or a site, with its truth (`truth.json`).
pub fn simulated(
    dir: &std::path::Path,
    out: &str,
    scene: &[&str],
) -> (std::path::PathBuf, pipemeasure::sim::truth::Truth) {
    let folder = simulate(dir, out, scene);
    let truth = pipemeasure::sim::truth::Truth::read(&folder.join("truth.json")).unwrap();
    (folder, truth)
}

/// The JSON content of `path` (a plant room's truth, a report).
pub fn read_json(path: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}
