//! TLS target coordinates: a CSV file with the header `id,x,y,z` (metres), one target per line.

use std::io::Write;
use std::path::Path;

use nalgebra::Point3;

use super::atomic::write_atomic;
use super::error::{ReadError, ReadErrorKind, WriteError, open_error};

/// A surveyed target.
#[derive(Clone, Debug, PartialEq)]
pub struct TlsTarget {
    /// Its id as written in the file.
    pub id: String,
    /// Coordinates (m).
    pub position: Point3<f64>,
}

/// Reads `id,x,y,z` targets. Blank lines and lines starting with `#` are skipped.
///
/// # Errors
///
/// [`ReadError`] naming the file and line: missing or wrong header, wrong field count, a
/// coordinate that is not a finite number, a repeated id.
pub fn read_targets(path: &Path) -> Result<Vec<TlsTarget>, ReadError> {
    let text = std::fs::read_to_string(path).map_err(|e| open_error(path, e))?;
    parse_targets(path, &text)
}

/// Parses the text of a target list (`path` only names it in errors).
///
/// # Errors
///
/// As [`read_targets`].
pub fn parse_targets(path: &Path, text: &str) -> Result<Vec<TlsTarget>, ReadError> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((hl, header)) = lines.next() else {
        return Err(ReadError::new(
            path,
            ReadErrorKind::Invalid("empty file: expected the header `id,x,y,z`".into()),
        ));
    };
    let cols: Vec<String> = header
        .split(',')
        .map(|c| c.trim().to_ascii_lowercase())
        .collect();
    if cols != ["id", "x", "y", "z"] {
        return Err(ReadError::at_line(
            path,
            hl + 1,
            ReadErrorKind::Invalid(format!(
                "header is `{}`, expected `id,x,y,z`",
                header.trim()
            )),
        ));
    }
    let mut out: Vec<TlsTarget> = Vec::new();
    let mut ids = std::collections::HashSet::new();
    for (k, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 4 {
            return Err(ReadError::at_line(
                path,
                k + 1,
                ReadErrorKind::FieldCount {
                    expected: "4 fields: id,x,y,z".into(),
                    found: f.len(),
                },
            ));
        }
        let mut xyz = [0.0; 3];
        for (i, name) in ["x", "y", "z"].into_iter().enumerate() {
            xyz[i] = f[i + 1]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    ReadError::at_line(
                        path,
                        k + 1,
                        ReadErrorKind::Field {
                            field: name,
                            value: f[i + 1].to_string(),
                            expected: "a finite number (metres)",
                        },
                    )
                })?;
        }
        if f[0].is_empty() || !ids.insert(f[0]) {
            return Err(ReadError::at_line(
                path,
                k + 1,
                ReadErrorKind::Invalid(format!("target id `{}` is empty or repeated", f[0])),
            ));
        }
        out.push(TlsTarget {
            id: f[0].to_string(),
            position: Point3::from(xyz),
        });
    }
    Ok(out)
}

/// Writes targets as `id,x,y,z` (shortest exact decimals), atomically.
///
/// # Errors
///
/// [`WriteError`].
pub fn write_targets(path: &Path, targets: &[TlsTarget]) -> Result<(), WriteError> {
    write_atomic(path, |w| {
        writeln!(w, "id,x,y,z")?;
        for t in targets {
            writeln!(
                w,
                "{},{:?},{:?},{:?}",
                t.id, t.position.x, t.position.y, t.position.z
            )?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.csv");
        let t = vec![
            TlsTarget {
                id: "1".into(),
                position: Point3::new(512_345.678_9, 5_612_345.1, 12.25),
            },
            TlsTarget {
                id: "T2".into(),
                position: Point3::new(-0.1, 0.2, 1.0 / 3.0),
            },
        ];
        write_targets(&p, &t).unwrap();
        assert_eq!(read_targets(&p).unwrap(), t);
        std::fs::write(&p, "# survey\nid,x,y,z\n1,0,0,0\n2,1,abc,0\n").unwrap();
        let e = read_targets(&p).unwrap_err().to_string();
        assert!(e.contains("t.csv:4") && e.contains("field y"), "{e}");
        std::fs::write(&p, "name,e,n,h\n").unwrap();
        assert!(
            read_targets(&p)
                .unwrap_err()
                .to_string()
                .contains("t.csv:1")
        );
        std::fs::write(&p, "id,x,y,z\n1,0,0,0\n1,1,1,1\n").unwrap();
        assert!(
            read_targets(&p)
                .unwrap_err()
                .to_string()
                .contains("repeated")
        );
    }
}
