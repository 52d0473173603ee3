//! Finding a profile by name: the folders searched, in order, and the presets built into the
//! binary.
//!
//! `--device NAME` is looked up as `NAME.json` in, in order: `$PIPEMEASURE_CALIBRATIONS`;
//! `./calibrations/`; the user's data folder (`$XDG_DATA_HOME/pipemeasure/calibrations`, by
//! default `~/.local/share/pipemeasure/calibrations` on Linux, the platform's equivalent
//! elsewhere, as the `directories` crate gives it); the presets built into the binary. A
//! `--device` with a path separator or ending in `.json` is a path to a profile file. The
//! first folder that has the name wins, so a profile a user calibrated shadows a preset of
//! the same name, and a project's `./calibrations/` shadows the user's own.

use std::path::{Path, PathBuf};

use super::{CALIBRATIONS_DIR, CALIBRATIONS_ENV, Profile, ProfileError};
use crate::io::error::{ReadError, ReadErrorKind};

/// The presets built into the binary: the repository's `calibrations/` at build time (the
/// paper's three phones), so `--device p30` works from any folder after an install.
pub const PRESETS: [(&str, &str); 3] = [
    ("iphone11", include_str!("../../calibrations/iphone11.json")),
    ("p30", include_str!("../../calibrations/p30.json")),
    ("s10", include_str!("../../calibrations/s10.json")),
];

/// Where a profile was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// `--device` gave a path to the file.
    Path,
    /// The folder named by `$PIPEMEASURE_CALIBRATIONS`.
    Env,
    /// `./calibrations/` in the working folder.
    WorkingFolder,
    /// The user's data folder ([`user_data_folder`]).
    UserData,
    /// A preset built into the binary ([`PRESETS`]).
    BuiltIn,
}

impl Origin {
    /// A short label for listings and messages.
    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Origin::Path => "path",
            Origin::Env => "$PIPEMEASURE_CALIBRATIONS",
            Origin::WorkingFolder => "./calibrations",
            Origin::UserData => "user data folder",
            Origin::BuiltIn => "built in",
        }
    }
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.label())
    }
}

/// A folder searched for profiles by name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ProfileFolder {
    /// Which of the search path's places it is.
    pub origin: Origin,
    /// The folder.
    pub path: PathBuf,
}

/// A profile found by [`find_device`]: where, and its file (for a built-in preset a label,
/// `(built in)/NAME.json`, not a file on disk).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Located {
    /// Where it was found.
    pub origin: Origin,
    /// Its file, or the label of a built-in preset.
    pub path: PathBuf,
}

/// The user's profile folder: `pipemeasure/calibrations` in the platform's data folder
/// (`$XDG_DATA_HOME`, else `~/.local/share`, on Linux); `None` when the platform gives none
/// (no home folder).
#[must_use]
pub fn user_data_folder() -> Option<PathBuf> {
    directories::ProjectDirs::from("", "", "pipemeasure")
        .map(|d| d.data_dir().join(CALIBRATIONS_DIR))
}

/// The folders searched for profiles by name, in order (the built-in presets come after
/// them).
#[must_use]
pub fn search_folders() -> Vec<ProfileFolder> {
    let mut dirs = Vec::new();
    if let Some(env) = std::env::var_os(CALIBRATIONS_ENV).filter(|v| !v.is_empty()) {
        dirs.push(ProfileFolder {
            origin: Origin::Env,
            path: PathBuf::from(env),
        });
    }
    dirs.push(ProfileFolder {
        origin: Origin::WorkingFolder,
        path: PathBuf::from(CALIBRATIONS_DIR),
    });
    if let Some(path) = user_data_folder() {
        dirs.push(ProfileFolder {
            origin: Origin::UserData,
            path,
        });
    }
    dirs
}

/// Where `calibrate` writes a profile when no `--out` is given: the folder of
/// `$PIPEMEASURE_CALIBRATIONS` when it is set (a profile written elsewhere would be shadowed
/// by one of the same name there), else the user's data folder.
///
/// # Errors
///
/// [`ProfileError::NoDataFolder`] when neither is known.
pub fn default_profile_folder() -> Result<ProfileFolder, ProfileError> {
    search_folders()
        .into_iter()
        .find(|f| matches!(f.origin, Origin::Env | Origin::UserData))
        .ok_or(ProfileError::NoDataFolder)
}

/// The text of the built-in preset `name`.
#[must_use]
pub fn preset_text(name: &str) -> Option<&'static str> {
    PRESETS.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

/// The label standing for a built-in preset's file in messages and records.
#[must_use]
pub fn preset_label(name: &str) -> PathBuf {
    PathBuf::from(format!("(built in)/{name}.json"))
}

/// Device names in the folder `dir` (stems of its `*.json` files; a folder named `x.json` is
/// no profile), sorted; none when it cannot be read.
#[must_use]
pub fn devices_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| {
            let p = e.ok()?.path();
            (p.extension()? == "json" && p.is_file())
                .then(|| p.file_stem()?.to_str().map(str::to_string))?
        })
        .collect();
    names.sort();
    names
}

/// One profile of [`list_profiles`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Listed {
    /// The device name.
    pub name: String,
    /// Where it is.
    pub located: Located,
    /// The place of the profile of the same name found first, when this one is not.
    pub shadowed_by: Option<Origin>,
}

/// Every profile in the search path, in lookup order within each name, names sorted: those a
/// name finds first and those they shadow.
#[must_use]
pub fn list_profiles() -> Vec<Listed> {
    let mut all: Vec<(String, Located)> = Vec::new();
    for folder in search_folders() {
        for name in devices_in(&folder.path) {
            let path = folder.path.join(format!("{name}.json"));
            all.push((
                name,
                Located {
                    origin: folder.origin,
                    path,
                },
            ));
        }
    }
    for (name, _) in PRESETS {
        all.push((
            name.to_string(),
            Located {
                origin: Origin::BuiltIn,
                path: preset_label(name),
            },
        ));
    }
    // A stable sort keeps the lookup order within a name.
    all.sort_by(|a, b| a.0.cmp(&b.0));
    let mut listed: Vec<Listed> = Vec::with_capacity(all.len());
    for (name, located) in all {
        let shadowed_by = listed
            .iter()
            .find(|l| l.name == name && l.shadowed_by.is_none())
            .map(|l| l.located.origin);
        listed.push(Listed {
            name,
            located,
            shadowed_by,
        });
    }
    listed
}

/// Device names available in the search path and among the presets, sorted, unique.
#[must_use]
pub fn available_devices() -> Vec<String> {
    let mut names: Vec<String> = list_profiles().into_iter().map(|l| l.name).collect();
    names.dedup();
    names
}

/// Whether `--device` names a file rather than a device.
fn looks_like_path(spec: &str) -> bool {
    spec.contains('/') || spec.contains(std::path::MAIN_SEPARATOR) || spec.ends_with(".json")
}

/// Checks that `name` is a device name, not a path: not empty, no path separator (`/`, `\`),
/// no leading `.` (no `..`, no hidden file), no control character, not ending in `.json`. A
/// profile is written as `NAME.json` in a profile folder, so a name can never write outside
/// it.
///
/// # Errors
///
/// [`ProfileError::NotAName`].
pub fn validate_device_name(name: &str) -> Result<(), ProfileError> {
    let ok = !name.trim().is_empty()
        && !name.starts_with('.')
        && !name.ends_with(".json")
        && !name
            .chars()
            .any(|c| c == '/' || c == '\\' || c == std::path::MAIN_SEPARATOR || c.is_control());
    if ok {
        Ok(())
    } else {
        Err(ProfileError::NotAName(name.to_string()))
    }
}

/// The profile `--device name` finds from the working folder when it is not the file
/// `written` (a `./calibrations/NAME.json` here, or one in `$PIPEMEASURE_CALIBRATIONS`, found
/// before a profile just written to the user's data folder); `None` when it is that file or
/// the name finds nothing. Paths are compared as the file system resolves them.
#[must_use]
pub fn shadowing(name: &str, written: &Path) -> Option<Located> {
    let found = find_device(name).ok()?;
    let same = match (found.path.canonicalize(), written.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => found.path == written,
    };
    (!same).then_some(found)
}

/// Finds `--device`: a path, or a name in the search folders, then among the presets.
///
/// # Errors
///
/// [`ProfileError::UnknownDevice`] naming every folder searched and the available devices, or
/// a not-found read error for a path.
pub fn find_device(spec: &str) -> Result<Located, ProfileError> {
    let file = |p: PathBuf| -> Result<Option<PathBuf>, ProfileError> {
        if p.is_dir() {
            return Err(ReadError::new(p, ReadErrorKind::IsDirectory).into());
        }
        Ok(p.is_file().then_some(p))
    };
    if looks_like_path(spec) {
        let p = PathBuf::from(spec);
        let path = file(p.clone())?
            .ok_or_else(|| ProfileError::from(ReadError::new(p, ReadErrorKind::NotFound)))?;
        return Ok(Located {
            origin: Origin::Path,
            path,
        });
    }
    let folders = search_folders();
    for f in &folders {
        if let Some(path) = file(f.path.join(format!("{spec}.json")))? {
            return Ok(Located {
                origin: f.origin,
                path,
            });
        }
    }
    if preset_text(spec).is_some() {
        return Ok(Located {
            origin: Origin::BuiltIn,
            path: preset_label(spec),
        });
    }
    Err(ProfileError::UnknownDevice {
        name: spec.to_string(),
        searched: folders
            .iter()
            .map(|f| format!("{} ({})", f.path.display(), f.origin))
            .collect::<Vec<_>>()
            .join(", "),
        available: available_devices().join(", "),
    })
}

/// Finds and reads `--device` ([`find_device`]); a built-in preset is parsed from the text
/// built into the binary.
///
/// # Errors
///
/// As [`find_device`], [`Profile::read`] and [`Profile::from_json`].
pub fn load_located(spec: &str) -> Result<(Located, Profile), ProfileError> {
    let located = find_device(spec)?;
    let profile = match located.origin {
        // Parsed and validated as a file would be.
        Origin::BuiltIn => {
            Profile::from_json(preset_text(spec).unwrap_or_default(), &located.path)?
        }
        _ => Profile::read(&located.path)?,
    };
    Ok((located, profile))
}

/// Finds and reads `--device`: its file (or a built-in preset's label) and the profile.
///
/// # Errors
///
/// As [`load_located`].
pub fn load_device(spec: &str) -> Result<(PathBuf, Profile), ProfileError> {
    load_located(spec).map(|(l, p)| (l.path, p))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A profile path that is a directory gave "not found".
    #[test]
    fn a_directory_is_not_a_profile() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("dir.json");
        std::fs::create_dir(&d).unwrap();
        for e in [
            Profile::read(&d).unwrap_err().to_string(),
            find_device(&d.display().to_string())
                .unwrap_err()
                .to_string(),
        ] {
            assert!(
                e.ends_with("dir.json: is a directory, expected a file"),
                "{e}"
            );
        }
    }

    /// `calibrate --device ../../escaped` without `--out` wrote outside the profile folder.
    #[test]
    fn device_names_are_names_not_paths() {
        for bad in [
            "../../escaped",
            "a/b",
            "a\\b",
            "..",
            ".hidden",
            "",
            " ",
            "p30.json",
            "x\ny",
        ] {
            assert!(
                matches!(validate_device_name(bad), Err(ProfileError::NotAName(_))),
                "{bad:?}"
            );
        }
        for good in ["p30", "Pixel 7 Pro", "iphone11-4k.60fps", "pipe_cam"] {
            validate_device_name(good).unwrap();
        }
    }

    /// Every preset built in parses, passes validation and is the device its name says.
    #[test]
    fn the_built_in_presets_are_valid_profiles_of_their_names() {
        for (name, text) in PRESETS {
            let label = preset_label(name);
            // from_json validates every value.
            let p = Profile::from_json(text, &label).unwrap();
            assert_eq!(p.device, name);
        }
    }
}
