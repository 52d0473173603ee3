//! The paper's experiments and the accuracy evaluations behind the README's tables (top layer:
//! may use every other module, including the simulator and the algorithms it judges).

pub mod calibration;
pub mod detection;
pub mod eccentricity;
pub mod matching;
pub mod pipe;
pub mod video_lab;

use serde::{Deserialize, Serialize};

use crate::sim::simulate::SimulateOptions;

/// The simulated runs behind a table: one per device preset, each at the same frame size,
/// frame count and seed (Table II, Table III and the video labs share this shape).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PresetRuns {
    /// Device presets.
    pub devices: Vec<String>,
    /// Frame width (16:9).
    pub width: u32,
    /// Frames of each simulated lab or site.
    pub frames: usize,
    /// Seed.
    pub seed: u64,
}

impl PresetRuns {
    /// Every device preset at `width` (16:9) with `frames` frames, seed 1.
    #[must_use]
    pub fn every_preset(width: u32, frames: usize) -> Self {
        PresetRuns {
            devices: crate::sim::devices::PRESETS
                .iter()
                .map(|p| p.name.to_string())
                .collect(),
            width,
            frames,
            seed: 1,
        }
    }

    /// The simulator's options for `device`'s run: its frame size (16:9), seed and `command`,
    /// everything else at the simulator's defaults.
    #[must_use]
    pub fn simulate_options(&self, device: &str, command: &str) -> SimulateOptions {
        SimulateOptions {
            device: device.to_string(),
            width: self.width,
            height: self.width * 9 / 16,
            seed: self.seed,
            command: command.to_string(),
            ..SimulateOptions::default()
        }
    }
}
