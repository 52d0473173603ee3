//! Dense observations (`dense/observations.bin`): the raw material of a dense reconstruction as
//! the simulator writes it — surface points with their pixel observations in several frames.
//!
//! Little-endian binary:
//!
//! ```text
//! "PMOBS001"                         magic, 8 bytes
//! u32 frame_count, then per frame: u16 name length, name bytes (UTF-8)
//! u16 label_count, then per label: u16 length, bytes  (label 0 = first name)
//! u64 point_count, then per point:
//!     u64 id, u8 label, f64 x, f64 y, f64 z      (true world position, metres)
//!     u8 observation_count, then per observation: u32 frame index, f32 u, f32 v (pixels)
//! ```

use std::io::Write;
use std::path::Path;

use nalgebra::{Point3, Vector2};

use super::atomic::write_atomic;
use super::error::{ReadError, ReadErrorKind, WriteError, open_error};

const MAGIC: &[u8; 8] = b"PMOBS001";

/// One observation of a point in a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelObservation {
    /// Index into [`DenseObservations::frames`].
    pub frame: u32,
    /// The observed pixel (COLMAP convention), as stored (f32 precision).
    pub uv: Vector2<f64>,
}

/// One surface point.
#[derive(Clone, Debug, PartialEq)]
pub struct DensePoint {
    /// Point id.
    pub id: u64,
    /// Index into [`DenseObservations::labels`].
    pub label: u8,
    /// True world position (m).
    pub position: Point3<f64>,
    /// Its observations (at most 255).
    pub observations: Vec<PixelObservation>,
}

/// A dense observation set.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DenseObservations {
    /// Frame file names, indexed by [`PixelObservation::frame`].
    pub frames: Vec<String>,
    /// Surface labels (`wall`, `floor`, pipe names), indexed by [`DensePoint::label`].
    pub labels: Vec<String>,
    /// The points.
    pub points: Vec<DensePoint>,
}

impl DenseObservations {
    /// Writes the set atomically.
    ///
    /// # Errors
    ///
    /// [`WriteError`]; also for names longer than 65535 bytes or more than 255 observations or
    /// labels.
    pub fn write(&self, path: &Path) -> Result<(), WriteError> {
        let invalid = |m: &str| {
            WriteError::new(
                path,
                std::io::Error::new(std::io::ErrorKind::InvalidInput, m.to_string()),
            )
        };
        if self.labels.len() > 256 || self.points.iter().any(|p| p.observations.len() > 255) {
            return Err(invalid(
                "more than 256 labels or 255 observations of a point",
            ));
        }
        if self
            .frames
            .iter()
            .chain(&self.labels)
            .any(|n| n.len() > usize::from(u16::MAX))
        {
            return Err(invalid("a name longer than 65535 bytes"));
        }
        write_atomic(path, |w| {
            w.write_all(MAGIC)?;
            w.write_all(&(self.frames.len() as u32).to_le_bytes())?;
            for name in &self.frames {
                w.write_all(&(name.len() as u16).to_le_bytes())?;
                w.write_all(name.as_bytes())?;
            }
            w.write_all(&(self.labels.len() as u16).to_le_bytes())?;
            for name in &self.labels {
                w.write_all(&(name.len() as u16).to_le_bytes())?;
                w.write_all(name.as_bytes())?;
            }
            w.write_all(&(self.points.len() as u64).to_le_bytes())?;
            for p in &self.points {
                w.write_all(&p.id.to_le_bytes())?;
                w.write_all(&[p.label])?;
                for v in [p.position.x, p.position.y, p.position.z] {
                    w.write_all(&v.to_le_bytes())?;
                }
                w.write_all(&[p.observations.len() as u8])?;
                for o in &p.observations {
                    w.write_all(&o.frame.to_le_bytes())?;
                    w.write_all(&(o.uv.x as f32).to_le_bytes())?;
                    w.write_all(&(o.uv.y as f32).to_le_bytes())?;
                }
            }
            Ok(())
        })
    }

    /// Reads a set.
    ///
    /// # Errors
    ///
    /// [`ReadError`] naming the file and byte offset: wrong magic, truncation, frame or label
    /// indices out of range.
    pub fn read(path: &Path) -> Result<Self, ReadError> {
        let data = std::fs::read(path).map_err(|e| open_error(path, e))?;
        Self::parse(path, &data)
    }

    /// Parses a set held in memory (`path` only names it in errors).
    ///
    /// # Errors
    ///
    /// As [`DenseObservations::read`].
    pub fn parse(path: &Path, data: &[u8]) -> Result<Self, ReadError> {
        let mut pos = 0usize;
        let take = |pos: &mut usize, n: usize, what: &str| -> Result<&[u8], ReadError> {
            if data.len() - *pos < n {
                return Err(ReadError::at_byte(
                    path,
                    *pos as u64,
                    ReadErrorKind::Truncated(format!("{what} needs {n} bytes")),
                ));
            }
            let s = &data[*pos..*pos + n];
            *pos += n;
            Ok(s)
        };
        if take(&mut pos, 8, "magic")? != MAGIC {
            return Err(ReadError::new(
                path,
                ReadErrorKind::WrongFormat("pipemeasure dense observations"),
            ));
        }
        let u16_at = |pos: &mut usize, what: &str| -> Result<u16, ReadError> {
            let b = take(pos, 2, what)?;
            Ok(u16::from_le_bytes([b[0], b[1]]))
        };
        let u32_at = |pos: &mut usize, what: &str| -> Result<u32, ReadError> {
            let b = take(pos, 4, what)?;
            Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        };
        let u64_at = |pos: &mut usize, what: &str| -> Result<u64, ReadError> {
            let b = take(pos, 8, what)?;
            let mut a = [0u8; 8];
            a.copy_from_slice(b);
            Ok(u64::from_le_bytes(a))
        };
        let string = |pos: &mut usize, what: &str| -> Result<String, ReadError> {
            let n = u16_at(pos, what)? as usize;
            let at = *pos;
            let b = take(pos, n, what)?;
            String::from_utf8(b.to_vec()).map_err(|_| {
                ReadError::at_byte(
                    path,
                    at as u64,
                    ReadErrorKind::Invalid(format!("{what} is not UTF-8")),
                )
            })
        };
        let nf = u32_at(&mut pos, "frame count")? as usize;
        let frames = (0..nf)
            .map(|_| string(&mut pos, "frame name"))
            .collect::<Result<Vec<_>, _>>()?;
        let nl = u16_at(&mut pos, "label count")? as usize;
        let labels = (0..nl)
            .map(|_| string(&mut pos, "label"))
            .collect::<Result<Vec<_>, _>>()?;
        let np = u64_at(&mut pos, "point count")?;
        // Each point takes at least 34 bytes: never allocate beyond what the file can hold.
        let cap = (np as usize).min((data.len() - pos) / 34);
        let mut points = Vec::with_capacity(cap);
        for _ in 0..np {
            let at = pos;
            let id = u64_at(&mut pos, "point id")?;
            let label = take(&mut pos, 1, "label")?[0];
            if usize::from(label) >= labels.len() {
                return Err(ReadError::at_byte(
                    path,
                    at as u64,
                    ReadErrorKind::Invalid(format!(
                        "point {id} has label {label} of {}",
                        labels.len()
                    )),
                ));
            }
            let mut xyz = [0.0; 3];
            for v in &mut xyz {
                *v = f64::from_bits(u64_at(&mut pos, "coordinate")?);
            }
            let n = take(&mut pos, 1, "observation count")?[0];
            let mut observations = Vec::with_capacity(usize::from(n));
            for _ in 0..n {
                let at = pos;
                let frame = u32_at(&mut pos, "frame index")?;
                if frame as usize >= frames.len() {
                    return Err(ReadError::at_byte(
                        path,
                        at as u64,
                        ReadErrorKind::Invalid(format!(
                            "point {id} refers to frame {frame} of {}",
                            frames.len()
                        )),
                    ));
                }
                let u = f32::from_bits(u32_at(&mut pos, "u")?);
                let v = f32::from_bits(u32_at(&mut pos, "v")?);
                observations.push(PixelObservation {
                    frame,
                    uv: Vector2::new(f64::from(u), f64::from(v)),
                });
            }
            points.push(DensePoint {
                id,
                label,
                position: Point3::from(xyz),
                observations,
            });
        }
        if pos != data.len() {
            return Err(ReadError::at_byte(
                path,
                pos as u64,
                ReadErrorKind::Invalid("unexpected bytes after the last point".into()),
            ));
        }
        Ok(DenseObservations {
            frames,
            labels,
            points,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> DenseObservations {
        DenseObservations {
            frames: vec!["frame_0001.png".into(), "frame_0002.png".into()],
            labels: vec!["wall".into(), "pipe_4in".into()],
            points: vec![
                DensePoint {
                    id: 7,
                    label: 1,
                    position: Point3::new(0.1, -0.2, 1.5),
                    observations: vec![
                        PixelObservation {
                            frame: 0,
                            uv: Vector2::new(100.5, 200.25),
                        },
                        PixelObservation {
                            frame: 1,
                            uv: Vector2::new(1.0, 2.0),
                        },
                    ],
                },
                DensePoint {
                    id: 8,
                    label: 0,
                    position: Point3::new(1e6, 2.0, 3.0),
                    observations: vec![],
                },
            ],
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("obs.bin");
        sample().write(&p).unwrap();
        assert_eq!(DenseObservations::read(&p).unwrap(), sample());
    }

    #[test]
    fn corrupt_files_name_the_byte() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("obs.bin");
        sample().write(&p).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 3]).unwrap();
        let e = DenseObservations::read(&p).unwrap_err().to_string();
        assert!(
            e.contains("obs.bin (byte") && e.contains("ends early"),
            "{e}"
        );
        std::fs::write(&p, b"NOTMAGIC").unwrap();
        assert!(
            DenseObservations::read(&p)
                .unwrap_err()
                .to_string()
                .contains("not a pipemeasure dense observations file")
        );
    }
}
