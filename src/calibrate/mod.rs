//! The calibration job (layer 3): paper Algorithm 1 (`refine`: robust two-view geometry and
//! robust triangulation of the SfM features), Algorithm 2 (`matching`: ellipse matching across
//! views), Algorithm 3 (`eccentricity`: the image of each target's true centre), on the
//! frames' cameras and detections in undistorted pixel coordinates (`views`).

pub mod check_points;
pub mod checks;
pub mod device;
pub mod eccentricity;
pub mod input;
pub mod jackknife;
pub mod matching;
pub mod neighbours;
pub mod network;
pub mod pipeline;
pub mod poses;
pub mod refine;
pub mod selection;
pub mod track;
pub mod tracks;
pub mod views;

pub use device::{CrossValidation, DeviceCalibration, DeviceConfig, calibrate_device};
pub use pipeline::{
    CalibrateConfig, CalibrateError, Calibration, CalibrationInput, ReadoutStart, Termination,
    calibrate,
};
