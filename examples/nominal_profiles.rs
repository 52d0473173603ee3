//! Writes `calibrations/NAME.json` for each simulator device preset with its *nominal* (true)
//! intrinsics and no statistics, marked as such in `provenance`. These stand in until
//! `pipemeasure calibrate` produces real profiles from simulated labs.
//!
//! `cargo run --example nominal_profiles -- [DIR] [--force]`

use std::collections::BTreeMap;
use std::path::PathBuf;

use pipemeasure::profile::Profile;
use pipemeasure::sim::devices::PRESETS;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let force = args.iter().any(|a| a == "--force");
    let dir = args
        .iter()
        .find(|a| !a.starts_with("--"))
        .map_or_else(|| PathBuf::from("calibrations"), PathBuf::from);
    for preset in PRESETS {
        let provenance = BTreeMap::from([
            ("source".to_string(), "nominal".into()),
            (
                "note".to_string(),
                format!(
                    "true intrinsics of the simulator's {} preset (src/sim/devices.rs), not a \
                     calibration: calibrate your own phone with `pipemeasure calibrate`",
                    preset.label
                )
                .into(),
            ),
            (
                "command".to_string(),
                "cargo run --example nominal_profiles".into(),
            ),
            (
                "tool".to_string(),
                format!("pipemeasure {}", env!("CARGO_PKG_VERSION")).into(),
            ),
        ]);
        let profile = Profile::uncalibrated(preset.name, &preset.camera, provenance);
        let path = dir.join(format!("{}.json", preset.name));
        profile.write(&path, force)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
