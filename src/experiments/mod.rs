//! The paper's experiments and the accuracy evaluations behind the README's tables (top layer:
//! may use every other module, including the simulator and the algorithms it judges).

pub mod calibration;
pub mod detection;
pub mod eccentricity;
pub mod matching;
pub mod pipe;
pub mod video_lab;
