//! Reader for the "Bundle Adjustment in the Large" (BAL) text format (Agarwal et al. 2010), the
//! public benchmark the bundle adjustment engine is timed on.
//!
//! ```text
//! num_cameras num_points num_observations
//! camera_index point_index x y          (one line per observation)
//! 9 numbers per camera: Rodrigues rotation (3), translation (3), f, k1, k2
//! 3 numbers per point
//! ```
//!
//! Projection (as the format documents): `P = R·X + t`, `p = −P / P.z`,
//! `pixel = f·(1 + k1·|p|² + k2·|p|⁴)·p`, origin at the image centre.

use std::path::Path;

use super::error::{ReadError, ReadErrorKind, open_error};

/// One BAL observation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalObservation {
    /// Index of the camera.
    pub camera: usize,
    /// Index of the point.
    pub point: usize,
    /// Measured image coordinates (origin at the image centre, y up).
    pub xy: [f64; 2],
}

/// A BAL problem as stored in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct BalProblem {
    /// Per camera: rotation vector (3), translation (3), f, k1, k2.
    pub cameras: Vec<[f64; 9]>,
    /// 3D points.
    pub points: Vec<[f64; 3]>,
    /// Observations.
    pub observations: Vec<BalObservation>,
}

/// Reads a BAL problem file.
///
/// # Errors
/// The file cannot be read, a number does not parse, an index is out of range or the file ends
/// early; the error names the file and the line.
pub fn read_bal(path: &Path) -> Result<BalProblem, ReadError> {
    let text = std::fs::read_to_string(path).map_err(|e| open_error(path, e))?;
    parse_bal(path, &text)
}

/// Parses the text of a BAL file (`path` only names it in errors).
///
/// # Errors
/// See [`read_bal`].
pub fn parse_bal(path: &Path, text: &str) -> Result<BalProblem, ReadError> {
    let mut tokens = Tokens::new(text);
    let n_cameras = tokens.count(path, "num_cameras")?;
    let n_points = tokens.count(path, "num_points")?;
    let n_observations = tokens.count(path, "num_observations")?;
    // Every number takes at least two bytes (a digit and a separator): counts the text cannot
    // hold are refused before anything is allocated or looped.
    let needed = 8u128 * n_observations as u128 + 18 * n_cameras as u128 + 6 * n_points as u128;
    if needed > text.len() as u128 {
        return Err(ReadError::at_line(
            path,
            1,
            ReadErrorKind::Truncated(format!(
                "the header declares {n_cameras} cameras, {n_points} points and {n_observations} \
                 observations, which need at least {needed} bytes; the file has {}",
                text.len()
            )),
        ));
    }
    let mut observations = Vec::with_capacity(n_observations);
    for _ in 0..n_observations {
        let camera = tokens.count(path, "camera_index")?;
        let line = tokens.line;
        let point = tokens.count(path, "point_index")?;
        if camera >= n_cameras || point >= n_points {
            return Err(ReadError::at_line(
                path,
                line,
                ReadErrorKind::Invalid(format!(
                    "observation of camera {camera}, point {point}: the header declares \
                     {n_cameras} cameras and {n_points} points"
                )),
            ));
        }
        let x = tokens.real(path, "x")?;
        let y = tokens.real(path, "y")?;
        observations.push(BalObservation {
            camera,
            point,
            xy: [x, y],
        });
    }
    let mut cameras = Vec::with_capacity(n_cameras);
    for _ in 0..n_cameras {
        let mut c = [0.0; 9];
        for v in &mut c {
            *v = tokens.real(path, "camera parameter")?;
        }
        cameras.push(c);
    }
    let mut points = Vec::with_capacity(n_points);
    for _ in 0..n_points {
        let mut p = [0.0; 3];
        for v in &mut p {
            *v = tokens.real(path, "point coordinate")?;
        }
        points.push(p);
    }
    Ok(BalProblem {
        cameras,
        points,
        observations,
    })
}

/// Whitespace-separated tokens with the 1-based line each starts on.
struct Tokens<'a> {
    rest: &'a str,
    line: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str) -> Self {
        Tokens {
            rest: text,
            line: 1,
        }
    }

    fn next_token(&mut self, path: &Path, what: &'static str) -> Result<&'a str, ReadError> {
        let trimmed = self.rest.trim_start_matches(|c: char| {
            if c == '\n' {
                self.line += 1;
            }
            c.is_whitespace()
        });
        let end = trimmed.find(char::is_whitespace).unwrap_or(trimmed.len());
        if end == 0 {
            return Err(ReadError::at_line(
                path,
                self.line,
                ReadErrorKind::Truncated(format!("expected {what}")),
            ));
        }
        let (token, rest) = trimmed.split_at(end);
        self.rest = rest;
        Ok(token)
    }

    fn count(&mut self, path: &Path, what: &'static str) -> Result<usize, ReadError> {
        let token = self.next_token(path, what)?;
        token.parse().map_err(|_| {
            ReadError::at_line(
                path,
                self.line,
                ReadErrorKind::Field {
                    field: what,
                    value: token.to_owned(),
                    expected: "a non-negative integer",
                },
            )
        })
    }

    fn real(&mut self, path: &Path, what: &'static str) -> Result<f64, ReadError> {
        let token = self.next_token(path, what)?;
        match token.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(ReadError::at_line(
                path,
                self.line,
                ReadErrorKind::Field {
                    field: what,
                    value: token.to_owned(),
                    expected: "a finite number",
                },
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &str = "2 1 2\n0 0 1.5 -2.0\n1 0 3e-1 4\n\
        0.1\n0.2\n0.3\n1\n2\n3\n500\n0.01\n-0.002\n\
        0\n0\n0\n0\n0\n5\n400\n0\n0\n\
        1.0\n2.0\n-3.0\n";

    #[test]
    fn parses_every_section() {
        let p = parse_bal(Path::new("tiny.txt"), TINY).unwrap();
        assert_eq!(p.cameras.len(), 2);
        assert_eq!(p.points, vec![[1.0, 2.0, -3.0]]);
        assert_eq!(
            p.observations[1],
            BalObservation {
                camera: 1,
                point: 0,
                xy: [0.3, 4.0]
            }
        );
        assert_eq!(
            p.cameras[0],
            [0.1, 0.2, 0.3, 1.0, 2.0, 3.0, 500.0, 0.01, -0.002]
        );
    }

    #[test]
    fn errors_name_the_line() {
        let bad = TINY.replace("1 0 3e-1 4", "1 0 3e-1 x");
        let e = parse_bal(Path::new("tiny.txt"), &bad).unwrap_err();
        assert_eq!(e.location, Some(super::super::Location::Line(3)));
        let out_of_range = TINY.replace("1 0 3e-1 4", "2 0 3e-1 4");
        let e = parse_bal(Path::new("tiny.txt"), &out_of_range).unwrap_err();
        assert!(e.to_string().contains("camera 2"), "{e}");
        let truncated = &TINY[..TINY.len() - 6];
        let e = parse_bal(Path::new("tiny.txt"), truncated).unwrap_err();
        assert!(matches!(e.kind, ReadErrorKind::Truncated(_)), "{e}");
    }

    /// A 40-byte file declaring 10⁹ observations reserved 512 MB before failing.
    #[test]
    fn lying_counts_are_refused_before_allocating() {
        let e = parse_bal(
            Path::new("lie.txt"),
            "1000000000 1000000000 1000000000\n0 0 1 1\n",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("lie.txt:1: file ends early: the header declares 1000000000 cameras"),
            "{e}"
        );
    }
}
