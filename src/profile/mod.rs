//! Device profiles: `NAME.json` (schema `pipemeasure.profile/1`, DESIGN.md "Conventions"),
//! their validation, where they are found ([`lookup`]) and the profile of a calibration
//! ([`calibrated`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::camera::{BrownCamera, Intrinsics, Term};
use std::io::Write as _;

use crate::io::atomic::StagedFile;
use crate::io::error::{ReadError, ReadErrorKind, WriteError, open_error};

pub mod calibrated;
pub mod lookup;

pub use calibrated::{CalibrationSource, HIGH_CORRELATION};
pub use lookup::{
    Listed, Located, Origin, PRESETS, ProfileFolder, available_devices, default_profile_folder,
    devices_in, find_device, list_profiles, load_device, load_located, search_folders, shadowing,
    user_data_folder, validate_device_name,
};

/// The schema tag of this profile format.
pub const PROFILE_SCHEMA: &str = "pipemeasure.profile/1";
/// Environment variable naming a folder of profiles, searched first.
pub const CALIBRATIONS_ENV: &str = "PIPEMEASURE_CALIBRATIONS";
/// The name of a profile folder: `./calibrations/` in the working folder, and
/// `pipemeasure/calibrations` in the user's data folder.
pub const CALIBRATIONS_DIR: &str = "calibrations";
/// The smallest pixel aspect fx / fy a profile may have (and the inverse the largest): real
/// cameras are within a percent of 1.
pub const MIN_PIXEL_ASPECT: f64 = 0.5;

/// Image size in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageSize {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
}

/// Standard deviations of the intrinsics (0 for terms not estimated).
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StdDev {
    /// σ of c (px).
    pub c: f64,
    /// σ of u0 (px).
    pub u0: f64,
    /// σ of v0 (px).
    pub v0: f64,
    /// σ of k1.
    pub k1: f64,
    /// σ of k2.
    pub k2: f64,
    /// σ of k3.
    pub k3: f64,
    /// σ of p1.
    pub p1: f64,
    /// σ of p2.
    pub p2: f64,
    /// σ of b1 (px).
    pub b1: f64,
    /// σ of b2 (px).
    pub b2: f64,
}

impl StdDev {
    /// The σ of one term.
    #[must_use]
    pub fn get(&self, term: Term) -> f64 {
        [
            self.c, self.u0, self.v0, self.k1, self.k2, self.k3, self.p1, self.p2, self.b1, self.b2,
        ][term.index()]
    }

    /// Sets the σ of one term.
    pub fn set(&mut self, term: Term, value: f64) {
        let slot = match term {
            Term::C => &mut self.c,
            Term::U0 => &mut self.u0,
            Term::V0 => &mut self.v0,
            Term::K1 => &mut self.k1,
            Term::K2 => &mut self.k2,
            Term::K3 => &mut self.k3,
            Term::P1 => &mut self.p1,
            Term::P2 => &mut self.p2,
            Term::B1 => &mut self.b1,
            Term::B2 => &mut self.b2,
        };
        *slot = value;
    }
}

/// Correlation coefficients of the estimated intrinsics.
#[derive(Clone, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Correlation {
    /// The terms, in matrix order.
    pub names: Vec<Term>,
    /// Symmetric matrix with a unit diagonal.
    pub matrix: Vec<Vec<f64>>,
}

/// A device profile: the calibrated camera of one phone and how it was obtained.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    /// Always [`PROFILE_SCHEMA`].
    pub schema: String,
    /// Device name (e.g. `p30`).
    pub device: String,
    /// Frame size the intrinsics refer to.
    pub image: ImageSize,
    /// Camera model; always `"brown"`.
    pub model: String,
    /// The terms that were estimated (the others are fixed, normally at 0).
    pub terms: Vec<Term>,
    /// The intrinsics.
    pub intrinsics: Intrinsics,
    /// Their standard deviations.
    #[serde(default)]
    pub std_dev: StdDev,
    /// Correlations of the estimated terms.
    #[serde(default)]
    pub correlation: Correlation,
    /// RMS of the image residuals of the calibration (px), if calibrated.
    #[serde(default)]
    pub residual_rms_px: Option<f64>,
    /// A-posteriori standard deviation of unit weight, if calibrated.
    #[serde(default)]
    pub sigma0: Option<f64>,
    /// Frames used.
    #[serde(default)]
    pub images: usize,
    /// Targets used.
    #[serde(default)]
    pub targets: usize,
    /// Image observations used.
    #[serde(default)]
    pub observations: usize,
    /// The rolling shutter: the device's readout time, when the calibration modelled it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rolling_shutter: Option<ReadoutTime>,
    /// Where the profile came from (tool, version, command, data, date, notes).
    #[serde(default)]
    pub provenance: BTreeMap<String, serde_json::Value>,
}

/// A rolling-shutter device's readout time: from the exposure of the top row to that of the
/// bottom row of a frame of [`Profile::image`]'s size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReadoutTime {
    /// Readout time (s).
    pub readout_s: f64,
    /// Its standard deviation (s); 0 when it was given, not estimated.
    pub readout_std_s: f64,
    /// Whether the calibration estimated it (video frames with their neighbours), or held
    /// it at a given value.
    pub estimated: bool,
}

/// Why a profile could not be found, read or accepted.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ProfileError {
    /// No profile of that name in the search path nor among the presets.
    #[error(
        "unknown device `{name}`: no {name}.json in {searched}, nor a preset built in; available devices: {available}"
    )]
    UnknownDevice {
        /// The name asked for.
        name: String,
        /// The folders searched, for the message.
        searched: String,
        /// Devices found, for the message.
        available: String,
    },
    /// The file could not be read or parsed.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The profile parsed but a value is unacceptable.
    #[error("{}: field `{field}` {reason}", .path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Path of the field, e.g. `intrinsics.c`.
        field: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The profile could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// A profile exists where one would be written.
    #[error("{} exists; replacing it keeps the old one as a numbered backup, {}", .0.display(), backup_path(.0, 1).display())]
    Exists(PathBuf),
    /// A device name that is not a plain name.
    #[error(
        "`{0}` is not a device name: a name has no path separator, does not start with `.` and does not end with `.json` (a profile is written as NAME.json in the profile folder; give a path to write elsewhere)"
    )]
    NotAName(String),
    /// Neither `$PIPEMEASURE_CALIBRATIONS` nor a user data folder is known to write a profile to.
    #[error(
        "no folder to write the profile to: no user data folder (the home folder is unknown) and $PIPEMEASURE_CALIBRATIONS is not set; give a path to write to"
    )]
    NoDataFolder,
}

impl Profile {
    /// A profile for a camera that has not been calibrated (σ = 0, no statistics), with the given
    /// provenance; used for nominal and imported cameras.
    #[must_use]
    pub fn uncalibrated(
        device: &str,
        camera: &BrownCamera,
        provenance: BTreeMap<String, serde_json::Value>,
    ) -> Self {
        Profile {
            schema: PROFILE_SCHEMA.into(),
            device: device.into(),
            image: ImageSize {
                width: camera.width,
                height: camera.height,
            },
            model: "brown".into(),
            terms: Vec::new(),
            intrinsics: camera.intrinsics,
            std_dev: StdDev::default(),
            correlation: Correlation::default(),
            residual_rms_px: None,
            sigma0: None,
            images: 0,
            targets: 0,
            observations: 0,
            rolling_shutter: None,
            provenance,
        }
    }

    /// The camera this profile describes.
    #[must_use]
    pub fn camera(&self) -> BrownCamera {
        BrownCamera {
            width: self.image.width,
            height: self.image.height,
            intrinsics: self.intrinsics,
        }
    }

    /// The covariance of the ten intrinsics (in [`Term::ALL`] order) from the σ and the
    /// correlation of the calibrated terms; zero for the fixed ones.
    #[must_use]
    pub fn covariance(&self) -> nalgebra::DMatrix<f64> {
        let mut cov = nalgebra::DMatrix::zeros(10, 10);
        let names = &self.correlation.names;
        for (i, a) in names.iter().enumerate() {
            for (j, b) in names.iter().enumerate() {
                let r = self
                    .correlation
                    .matrix
                    .get(i)
                    .and_then(|row| row.get(j))
                    .copied()
                    .unwrap_or(0.0);
                cov[(a.index(), b.index())] = r * self.std_dev.get(*a) * self.std_dev.get(*b);
            }
        }
        cov
    }

    /// Parses and validates a profile from JSON text; `path` is used in errors.
    ///
    /// # Errors
    ///
    /// [`ProfileError::Read`] with the field path (e.g. `intrinsics.c`) when the JSON does not
    /// match the schema; [`ProfileError::Invalid`] naming the field when a value is unacceptable.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, ProfileError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        let json_error = |field: String, inner: serde_json::Error| {
            let line = inner.line();
            let kind = ReadErrorKind::Json {
                field: if field == "." {
                    "(document)".into()
                } else {
                    field
                },
                message: strip_position(&inner.to_string()),
            };
            if line > 0 {
                ReadError::at_line(path, line, kind)
            } else {
                ReadError::new(path, kind)
            }
        };
        let profile: Profile = serde_path_to_error::deserialize(&mut *de).map_err(|e| {
            let field = e.path().to_string();
            json_error(field, e.into_inner())
        })?;
        // One profile per file: anything but white space after it (a second object) is an
        // error, not silently ignored.
        de.end().map_err(|e| json_error("(document)".into(), e))?;
        profile.validate(path)?;
        Ok(profile)
    }

    /// Reads and validates a profile file.
    ///
    /// # Errors
    ///
    /// As [`Profile::from_json`], plus a missing or unreadable file.
    pub fn read(path: &Path) -> Result<Self, ProfileError> {
        if path.is_dir() {
            return Err(ReadError::new(path, ReadErrorKind::IsDirectory).into());
        }
        let text = std::fs::read_to_string(path).map_err(|e| open_error(path, e))?;
        Self::from_json(&text, path)
    }

    /// Checks every value; `path` is used in errors.
    ///
    /// # Errors
    ///
    /// [`ProfileError::Invalid`] naming the first unacceptable field.
    pub fn validate(&self, path: &Path) -> Result<(), ProfileError> {
        let invalid = |field: &str, reason: String| ProfileError::Invalid {
            path: path.to_path_buf(),
            field: field.to_string(),
            reason,
        };
        if self.schema != PROFILE_SCHEMA {
            return Err(invalid(
                "schema",
                format!("is {:?}, expected {PROFILE_SCHEMA:?}", self.schema),
            ));
        }
        if self.model != "brown" {
            return Err(invalid(
                "model",
                format!("is {:?}, expected \"brown\"", self.model),
            ));
        }
        if self.device.trim().is_empty() {
            return Err(invalid("device", "is empty".into()));
        }
        use crate::io::frames::{MAX_FRAME_PIXELS, MAX_FRAME_SIDE_PX};
        for (field, v) in [
            ("image.width", self.image.width),
            ("image.height", self.image.height),
        ] {
            if !(1..=MAX_FRAME_SIDE_PX).contains(&v) {
                return Err(invalid(
                    field,
                    format!("is {v}, expected 1 to {MAX_FRAME_SIDE_PX} px"),
                ));
            }
        }
        let pixels = u64::from(self.image.width) * u64::from(self.image.height);
        if pixels > MAX_FRAME_PIXELS {
            return Err(invalid(
                "image",
                format!("is {pixels} pixels, more than the {MAX_FRAME_PIXELS} a frame may have"),
            ));
        }
        for term in Term::ALL {
            let v = self.intrinsics.get(term);
            if !v.is_finite() {
                return Err(invalid(
                    &format!("intrinsics.{term}"),
                    format!("is {v}, not a finite number"),
                ));
            }
            let s = self.std_dev.get(term);
            if !(s.is_finite() && s >= 0.0) {
                return Err(invalid(
                    &format!("std_dev.{term}"),
                    format!("is {s}, expected a finite value ≥ 0"),
                ));
            }
        }
        if self.intrinsics.c <= 0.0 {
            return Err(invalid(
                "intrinsics.c",
                format!("is {}, must be positive", self.intrinsics.c),
            ));
        }
        // fx = c + b1 and fy = c: a pixel aspect far from 1 is no camera (b1 = −c gives fx = 0).
        let aspect = (self.intrinsics.c + self.intrinsics.b1) / self.intrinsics.c;
        if !(MIN_PIXEL_ASPECT..=1.0 / MIN_PIXEL_ASPECT).contains(&aspect) {
            return Err(invalid(
                "intrinsics.b1",
                format!(
                    "is {}: fx = c + b1 = {} against fy = c = {}, a pixel aspect of {aspect:.3e} outside [{MIN_PIXEL_ASPECT}, {}]",
                    self.intrinsics.b1,
                    self.intrinsics.c + self.intrinsics.b1,
                    self.intrinsics.c,
                    1.0 / MIN_PIXEL_ASPECT
                ),
            ));
        }
        if let Some(r) = &self.rolling_shutter {
            if !(r.readout_s.is_finite() && r.readout_s >= 0.0 && r.readout_s < 1.0) {
                return Err(invalid(
                    "rolling_shutter.readout_s",
                    format!("is {}, expected a time in [0, 1) s", r.readout_s),
                ));
            }
            if !(r.readout_std_s.is_finite() && r.readout_std_s >= 0.0) {
                return Err(invalid(
                    "rolling_shutter.readout_std_s",
                    format!("is {}, expected a finite value ≥ 0", r.readout_std_s),
                ));
            }
        }
        let mut seen = std::collections::BTreeSet::new();
        for t in &self.terms {
            if !seen.insert(*t) {
                return Err(invalid("terms", format!("lists {t} twice")));
            }
        }
        let n = self.correlation.names.len();
        if self.correlation.matrix.len() != n {
            return Err(invalid(
                "correlation.matrix",
                format!("has {} rows for {n} names", self.correlation.matrix.len()),
            ));
        }
        // Every row's length before any value: the symmetry check reads the later rows.
        for (i, row) in self.correlation.matrix.iter().enumerate() {
            if row.len() != n {
                return Err(invalid(
                    &format!("correlation.matrix[{i}]"),
                    format!("has {} entries, expected {n}", row.len()),
                ));
            }
        }
        for (i, row) in self.correlation.matrix.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                let sym = self.correlation.matrix[j][i];
                let ok = v.is_finite()
                    && (-1.0 - 1e-9..=1.0 + 1e-9).contains(&v)
                    && (v - sym).abs() <= 1e-9;
                let diag_ok = i != j || (v - 1.0).abs() <= 1e-9;
                if !ok || !diag_ok {
                    return Err(invalid(
                        &format!("correlation.matrix[{i}][{j}]"),
                        format!(
                            "is {v}: a correlation matrix is symmetric, in [-1, 1], with 1 on the diagonal"
                        ),
                    ));
                }
            }
        }
        for (name, v) in [
            ("residual_rms_px", self.residual_rms_px),
            ("sigma0", self.sigma0),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                return Err(invalid(
                    name,
                    format!("is {v}, expected a finite value ≥ 0"),
                ));
            }
        }
        Ok(())
    }

    /// The profile as pretty JSON.
    ///
    /// # Panics
    ///
    /// Never: every field serialises.
    #[must_use]
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self)
            .unwrap_or_else(|e| unreachable!("profile serialises: {e}"))
    }

    /// Writes the profile atomically. An existing file is refused unless `force`, in which case
    /// it is first copied to a numbered backup ([`backup_path`]), whose path is returned.
    ///
    /// # Errors
    ///
    /// [`ProfileError::Exists`], [`ProfileError::Write`].
    pub fn write(&self, path: &Path, force: bool) -> Result<Option<PathBuf>, ProfileError> {
        self.stage(path, force)?.commit()
    }

    /// Writes the profile beside `path`, to be moved into place by [`StagedProfile::commit`]
    /// once the command's other outputs are written too. An existing file is refused unless
    /// `force`.
    ///
    /// # Errors
    ///
    /// [`ProfileError::Exists`], [`ProfileError::Write`].
    pub fn stage(&self, path: &Path, force: bool) -> Result<StagedProfile, ProfileError> {
        if path.exists() && !force {
            return Err(ProfileError::Exists(path.to_path_buf()));
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| WriteError::new(dir, e))?;
        }
        let text = format!("{}\n", self.to_json());
        let file = StagedFile::write(path, |w| w.write_all(text.as_bytes()))?;
        Ok(StagedProfile { file })
    }
}

/// A profile written beside its destination ([`Profile::stage`]).
#[derive(Debug)]
pub struct StagedProfile {
    file: StagedFile,
}

impl StagedProfile {
    /// Moves the profile into place; a profile already there is first copied to a numbered
    /// backup, never overwriting an earlier backup. Returns the backup's path, if one was made.
    ///
    /// # Errors
    ///
    /// [`ProfileError::Write`] naming the backup or the profile.
    pub fn commit(self) -> Result<Option<PathBuf>, ProfileError> {
        let path = self.file.destination().to_path_buf();
        let backup = if path.exists() {
            Some(backup_existing(&path)?)
        } else {
            None
        };
        self.file.commit()?;
        Ok(backup)
    }
}

/// The backup name of `path` with number `n`: `p30.json.1.bak`, `p30.json.2.bak`, … (the
/// `.bak` suffix kept, so that `*.bak` patterns still match).
#[must_use]
pub fn backup_path(path: &Path, n: u32) -> PathBuf {
    PathBuf::from(format!("{}.{n}.bak", path.display()))
}

/// Copies `path` to the first free numbered backup, created exclusively so that no backup is
/// ever overwritten (not even by a concurrent run).
fn backup_existing(path: &Path) -> Result<PathBuf, ProfileError> {
    let bytes = std::fs::read(path).map_err(|e| WriteError::new(path, e))?;
    let mut n = 1u32;
    loop {
        let backup = backup_path(path, n);
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&backup)
        {
            Ok(mut f) => {
                f.write_all(&bytes)
                    .and_then(|()| f.sync_all())
                    .map_err(|e| WriteError::new(&backup, e))?;
                return Ok(backup);
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(WriteError::new(&backup, e).into()),
        }
        n = n.checked_add(1).ok_or_else(|| {
            WriteError::new(path, std::io::Error::other("every backup number is taken"))
        })?;
    }
}

/// serde_json appends " at line L column C" to messages; the location is reported separately.
fn strip_position(message: &str) -> String {
    match message.rfind(" at line ") {
        Some(i) => message[..i].to_string(),
        None => message.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Profile {
        let cam = BrownCamera {
            width: 3840,
            height: 2160,
            intrinsics: Intrinsics {
                k1: 0.01,
                ..Intrinsics::pinhole(3000.0, 1920.0, 1080.0)
            },
        };
        let mut p = Profile::uncalibrated("test", &cam, BTreeMap::new());
        p.terms = vec![Term::C, Term::U0, Term::V0, Term::K1];
        p.std_dev.c = 0.5;
        p.correlation = Correlation {
            names: vec![Term::C, Term::K1],
            matrix: vec![vec![1.0, -0.3], vec![-0.3, 1.0]],
        };
        p.residual_rms_px = Some(0.05);
        p
    }

    #[test]
    fn json_round_trip() {
        let p = sample();
        let back = Profile::from_json(&p.to_json(), Path::new("x.json")).unwrap();
        assert_eq!(back, p);
    }

    #[track_caller]
    fn error_for(edit: impl Fn(&mut serde_json::Value)) -> String {
        let mut v: serde_json::Value = serde_json::from_str(&sample().to_json()).unwrap();
        edit(&mut v);
        let text = serde_json::to_string_pretty(&v).unwrap();
        Profile::from_json(&text, Path::new("p.json"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn malformed_profiles_name_the_field() {
        let e = error_for(|v| v["intrinsics"]["c"] = "big".into());
        assert!(e.contains("p.json") && e.contains("intrinsics.c"), "{e}");
        let e = error_for(|v| {
            v["intrinsics"].as_object_mut().unwrap().remove("u0");
        });
        assert!(
            e.contains("intrinsics") && e.contains("missing field `u0`"),
            "{e}"
        );
        let e = error_for(|v| v["intrinsics"]["k_1"] = 0.1.into());
        assert!(e.contains("intrinsics") && e.contains("k_1"), "{e}");
        let e = error_for(|v| v["intrinsics"]["c"] = (-5.0).into());
        assert!(
            e.contains("field `intrinsics.c`") && e.contains("positive"),
            "{e}"
        );
        let e = error_for(|v| v["image"]["width"] = 0.into());
        assert!(e.contains("image.width"), "{e}");
        let e = error_for(|v| v["image"]["height"] = 4_000_000_000u32.into());
        assert!(
            e.contains("field `image.height` is 4000000000, expected 1 to 65535 px"),
            "{e}"
        );
        let e = error_for(|v| v["image"]["width"] = 60_000.into());
        assert!(e.contains("field `image` is 129600000 pixels"), "{e}");
        let e = error_for(|v| v["schema"] = "pipemeasure.profile/9".into());
        assert!(e.contains("field `schema`"), "{e}");
        let e = error_for(|v| v["terms"] = serde_json::json!(["c", "k9"]));
        assert!(e.contains("terms[1]") && e.contains("k9"), "{e}");
        let e = error_for(|v| v["correlation"]["matrix"][0][1] = 0.5.into());
        assert!(e.contains("correlation.matrix[0][1]"), "{e}");
        let e = error_for(|v| v["std_dev"]["k1"] = (-1.0).into());
        assert!(e.contains("std_dev.k1"), "{e}");
        // A later row shorter than the names (found by the fuzz target `profile`: the
        // symmetry check read past its end).
        let e = error_for(|v| v["correlation"]["matrix"][1] = serde_json::json!([]));
        assert!(
            e.contains("correlation.matrix[1]") && e.contains("0 entries"),
            "{e}"
        );
        let e = Profile::from_json("{\"schema\": ", Path::new("p.json"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("p.json:1"), "{e}");
    }

    #[test]
    fn write_refuses_to_overwrite_without_force_and_keeps_a_backup() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("dev.json");
        let p = sample();
        p.write(&path, false).unwrap();
        assert!(matches!(
            p.write(&path, false),
            Err(ProfileError::Exists(_))
        ));
        let mut q = p.clone();
        q.intrinsics.c = 3001.0;
        q.write(&path, true).unwrap();
        assert_eq!(Profile::read(&path).unwrap().intrinsics.c, 3001.0);
        let backup = dir.path().join("dev.json.1.bak");
        assert_eq!(Profile::read(&backup).unwrap().intrinsics.c, 3000.0);
    }

    /// A second `--force` overwrote `.bak`, so the original profile was lost.
    #[test]
    fn backups_are_numbered_and_never_overwritten() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("dev.json");
        let mut p = sample();
        for c in [3000.0, 3001.0, 3002.0, 3003.0] {
            p.intrinsics.c = c;
            p.write(&path, true).unwrap();
        }
        let c_of = |name: &str| Profile::read(&dir.path().join(name)).unwrap().intrinsics.c;
        assert_eq!(c_of("dev.json"), 3003.0);
        assert_eq!(c_of("dev.json.1.bak"), 3000.0);
        assert_eq!(c_of("dev.json.2.bak"), 3001.0);
        assert_eq!(c_of("dev.json.3.bak"), 3002.0);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 4);
    }

    /// A profile followed by a second object was accepted.
    #[test]
    fn a_second_json_object_is_an_error() {
        let text = sample().to_json();
        let e = Profile::from_json(&format!("{text}\n{text}\n"), Path::new("p.json"))
            .unwrap_err()
            .to_string();
        let second = text.lines().count() + 1;
        assert!(
            e.starts_with(&format!("p.json:{second}: (document): trailing characters")),
            "{e}"
        );
        Profile::from_json(&format!("{text}\n \n"), Path::new("p.json")).unwrap();
    }

    /// `profile show` accepted fx = 0 (`b1 = −c`) when c + b1 came out a rounding
    /// error above zero.
    #[test]
    fn a_pixel_aspect_far_from_one_is_refused() {
        for b1 in [-3000.0, -3000.0 + 1e-9, -1600.0, 3100.0] {
            let e = error_for(|v| v["intrinsics"]["b1"] = b1.into());
            assert!(
                e.contains("field `intrinsics.b1`") && e.contains("pixel aspect"),
                "{e}"
            );
        }
        let mut v: serde_json::Value = serde_json::from_str(&sample().to_json()).unwrap();
        v["intrinsics"]["b1"] = 2.5.into();
        Profile::from_json(&v.to_string(), Path::new("p.json")).unwrap();
    }
}
