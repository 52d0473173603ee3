//! The frames sidecar `frames/frames.json` (schema [`FRAMES_SCHEMA`]): for each frame taken
//! from a video, its time and its neighbours in the video (the frames `±1/fps` away), whose
//! detections tie the frame's motion to time and so let the calibration estimate the
//! rolling shutter's readout time. Written by `pipemeasure simulate … --video` and
//! by the frame choice of `calibrate --video`; read by `calibrate`.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::error::{ReadError, ReadErrorKind, open_error};

/// Schema tag of the frames sidecar.
pub const FRAMES_SCHEMA: &str = "pipemeasure.frames/1";

/// Largest time offset of a neighbour from its frame (s): a neighbour is the next or previous
/// video frame, at most 1/10 s away at the lowest frame rates.
pub const MAX_NEIGHBOUR_DT_S: f64 = 0.1;

/// One entry of `frames/frames.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FramesEntry {
    /// File name relative to the frames folder.
    pub name: String,
    /// Its time in the video (s).
    pub time_s: f64,
    /// Its neighbours in the video.
    pub neighbours: Vec<NeighbourEntry>,
}

/// A neighbour in `frames/frames.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NeighbourEntry {
    /// File name relative to the frames folder.
    pub name: String,
    /// Time offset from its main frame (s).
    pub dt_s: f64,
}

/// `frames/frames.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FramesSidecar {
    /// Always [`FRAMES_SCHEMA`].
    pub schema: String,
    /// The extracted frames in order.
    pub frames: Vec<FramesEntry>,
}

impl FramesSidecar {
    /// Reads and checks a sidecar: its schema, finite times, neighbours at non-zero offsets of
    /// at most [`MAX_NEIGHBOUR_DT_S`], names that stay inside the frames folder, no frame
    /// listed twice.
    ///
    /// # Errors
    /// [`ReadError`] naming the file and the offending field.
    pub fn read(path: &Path) -> Result<Self, ReadError> {
        let text = std::fs::read_to_string(path).map_err(|e| open_error(path, e))?;
        Self::parse(&text, path)
    }

    /// [`FramesSidecar::read`] on text already read; `path` names it in errors.
    ///
    /// # Errors
    /// [`ReadError`] naming `path` and the offending field.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ReadError> {
        let sidecar: FramesSidecar = serde_json::from_str(text).map_err(|e| {
            ReadError::at_line(
                path,
                e.line(),
                ReadErrorKind::Json {
                    field: "frames.json".into(),
                    message: e.to_string(),
                },
            )
        })?;
        sidecar.validate().map_err(|(field, message)| {
            ReadError::new(path, ReadErrorKind::Json { field, message })
        })?;
        Ok(sidecar)
    }

    /// The checks of [`FramesSidecar::read`]: `Err((field, message))`.
    fn validate(&self) -> Result<(), (String, String)> {
        if self.schema != FRAMES_SCHEMA {
            return Err((
                "schema".into(),
                format!("is {:?}, expected {FRAMES_SCHEMA:?}", self.schema),
            ));
        }
        let mut names = std::collections::HashSet::new();
        for (i, f) in self.frames.iter().enumerate() {
            let at = |what: &str| format!("frames[{i}].{what}");
            check_name(&f.name).map_err(|m| (at("name"), m))?;
            if !names.insert(f.name.as_str()) {
                return Err((at("name"), format!("{:?} is listed twice", f.name)));
            }
            if !f.time_s.is_finite() {
                return Err((
                    at("time_s"),
                    format!("is {}, expected a finite time", f.time_s),
                ));
            }
            // A neighbour listed twice would be detected twice and counted twice.
            let mut neighbour_names = std::collections::HashSet::new();
            for (j, n) in f.neighbours.iter().enumerate() {
                let at = |what: &str| format!("frames[{i}].neighbours[{j}].{what}");
                check_name(&n.name).map_err(|m| (at("name"), m))?;
                if !neighbour_names.insert(n.name.as_str()) {
                    return Err((
                        at("name"),
                        format!("{:?} is listed twice for this frame", n.name),
                    ));
                }
                if !(n.dt_s.is_finite() && n.dt_s != 0.0 && n.dt_s.abs() <= MAX_NEIGHBOUR_DT_S) {
                    return Err((
                        at("dt_s"),
                        format!(
                            "is {}, expected a non-zero offset of at most {MAX_NEIGHBOUR_DT_S} s",
                            n.dt_s
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The neighbours of the frame `name`, if listed (a linear search: for many names, index
    /// [`FramesSidecar::frames`] by name once).
    #[must_use]
    pub fn neighbours_of(&self, name: &str) -> &[NeighbourEntry] {
        self.frames
            .iter()
            .find(|f| f.name == name)
            .map_or(&[], |f| f.neighbours.as_slice())
    }
}

/// A name relative to the frames folder: not empty, not absolute, no `..`.
fn check_name(name: &str) -> Result<(), String> {
    let p = Path::new(name);
    if name.is_empty()
        || p.is_absolute()
        || p.components()
            .any(|c| !matches!(c, std::path::Component::Normal(_)))
    {
        return Err(format!(
            "{name:?} is not a file name relative to the frames folder"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frames.json");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    #[test]
    fn a_valid_sidecar_reads_with_its_neighbours() {
        let (_d, p) = write(
            r#"{"schema":"pipemeasure.frames/1","frames":[{"name":"f1.png","time_s":1.0,
            "neighbours":[{"name":"neighbours/f1-1.png","dt_s":-0.04},{"name":"neighbours/f1+1.png","dt_s":0.04}]}]}"#,
        );
        let s = FramesSidecar::read(&p).unwrap();
        assert_eq!(s.neighbours_of("f1.png").len(), 2);
        assert_eq!(s.neighbours_of("f1.png")[0].dt_s, -0.04);
        assert!(s.neighbours_of("f2.png").is_empty());
    }

    #[test]
    fn a_lying_sidecar_names_the_field() {
        for (text, field) in [
            (r#"{"schema":"other/1","frames":[]}"#, "schema"),
            (
                r#"{"schema":"pipemeasure.frames/1","frames":[{"name":"../x.png","time_s":0,"neighbours":[]}]}"#,
                "frames[0].name",
            ),
            (
                r#"{"schema":"pipemeasure.frames/1","frames":[{"name":"a.png","time_s":0,"neighbours":[{"name":"b.png","dt_s":0.5}]}]}"#,
                "frames[0].neighbours[0].dt_s",
            ),
            (
                r#"{"schema":"pipemeasure.frames/1","frames":[{"name":"a.png","time_s":0,"neighbours":[]},{"name":"a.png","time_s":1,"neighbours":[]}]}"#,
                "frames[1].name",
            ),
        ] {
            let (_d, p) = write(text);
            let e = FramesSidecar::read(&p).unwrap_err().to_string();
            assert!(e.contains("frames.json") && e.contains(field), "{e}");
        }
        let (_d, p) = write("{\"schema\": 3,\n}");
        let e = FramesSidecar::read(&p).unwrap_err().to_string();
        assert!(e.contains("frames.json:"), "{e}");
    }

    /// A neighbour listed twice for one frame would be decoded and detected twice (and a
    /// hostile sidecar could list one frame's neighbour millions of times).
    #[test]
    fn a_neighbour_listed_twice_is_refused() {
        let (_d, p) = write(
            r#"{"schema":"pipemeasure.frames/1","frames":[{"name":"a.png","time_s":0,"neighbours":[{"name":"b.png","dt_s":0.04},{"name":"b.png","dt_s":-0.04}]}]}"#,
        );
        let e = FramesSidecar::read(&p).unwrap_err().to_string();
        assert!(
            e.contains("frames.json")
                && e.contains("frames[0].neighbours[1].name")
                && e.contains("listed twice"),
            "{e}"
        );
    }

    /// One object per file, as for profiles: a second one is an error, not ignored.
    #[test]
    fn a_sidecar_followed_by_a_second_object_is_refused() {
        let one = r#"{"schema":"pipemeasure.frames/1","frames":[]}"#;
        let (_d, p) = write(one);
        assert!(FramesSidecar::read(&p).is_ok());
        let (_d, p) = write(&format!("{one}\n{one}"));
        let e = FramesSidecar::read(&p).unwrap_err().to_string();
        assert!(e.contains("frames.json:2"), "{e}");
    }
}
