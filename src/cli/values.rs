//! Parsers of option values that clap runs while parsing, so that a value out of range is a
//! usage error (exit code 2, the option named by clap) before any work: finite numbers only,
//! each with the range its option allows.

use nalgebra::Vector3;

/// A finite number.
fn number(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("`{s}` is not a finite number"))
    }
}

/// A finite number > 0.
pub fn positive(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(format!("{v} must be positive"))
    }
}

/// A finite number ≥ 0.
pub fn non_negative(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("{v} must be 0 or more"))
    }
}

/// A TLS scan's angular step (mrad): a finite number in [0.5, 20] (finer than 0.5 mrad is
/// beyond a simulation's memory; coarser than 20 mrad sees no pipe).
pub fn step_mrad(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if (0.5..=20.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} must be between 0.5 and 20"))
    }
}

/// A target's smallest semi-minor axis: a finite number ≥ 1 px (the detector's own bound).
pub fn semi_minor_px(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    if v >= 1.0 {
        Ok(v)
    } else {
        Err(format!("{v} px: must be at least 1 px"))
    }
}

/// A fraction of outliers, in [0, 0.5].
pub fn outlier_fraction(s: &str) -> Result<f64, String> {
    let v = non_negative(s)?;
    if v > 0.5 {
        return Err(format!(
            "{s}: an outlier fraction must be between 0 and 0.5"
        ));
    }
    Ok(v)
}

/// A fraction in [0, 1).
pub fn below_one(s: &str) -> Result<f64, String> {
    let v = non_negative(s)?;
    if v < 1.0 {
        Ok(v)
    } else {
        Err(format!("{v} must be below 1"))
    }
}

/// A rolling shutter's readout time in ms: a finite number in (0, 100].
pub fn readout_ms(s: &str) -> Result<f64, String> {
    let v = positive(s)?;
    if v <= 100.0 {
        Ok(v)
    } else {
        Err(format!("{v} ms: must be at most 100 ms"))
    }
}

/// A frame rate: `1fps`, `0.5fps` or a bare number, above 0 and at most 30 frames/s.
pub fn frame_rate(s: &str) -> Result<f64, String> {
    let number_part = s.trim().strip_suffix("fps").unwrap_or(s.trim());
    let v = positive(number_part)?;
    if v <= 30.0 {
        Ok(v)
    } else {
        Err(format!("{v} frames/s: must be at most 30"))
    }
}

/// `X,Y,Z`: three finite numbers.
pub fn point(s: &str) -> Result<Vector3<f64>, String> {
    let v: Vec<f64> = s.split(',').map(number).collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] => Ok(Vector3::new(x, y, z)),
        _ => Err(format!("`{s}`: expected three numbers X,Y,Z")),
    }
}

/// `X,Y,Z`: a direction (three finite numbers, not all zero), returned as a unit vector.
pub fn direction(s: &str) -> Result<Vector3<f64>, String> {
    let v = point(s)?;
    // Scaled by the largest component first, so that tiny or huge components normalise.
    let m = v.amax();
    if m == 0.0 {
        return Err(format!(
            "`{s}` is not a direction: all three components are 0"
        ));
    }
    Ok((v / m).normalize())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_out_of_range_are_refused() {
        assert_eq!(positive("0.5"), Ok(0.5));
        for bad in ["0", "-1", "inf", "nan", "x", ""] {
            assert!(positive(bad).is_err(), "{bad}");
        }
        assert_eq!(non_negative("0"), Ok(0.0));
        assert!(non_negative("-1e-9").is_err());
        assert!(semi_minor_px("0.5").is_err());
        assert!(below_one("1").is_err());
        assert_eq!(readout_ms("20"), Ok(20.0));
        for bad in ["0", "-5", "100.5", "inf", "nan"] {
            assert!(readout_ms(bad).is_err(), "{bad}");
        }
        assert_eq!(point("1, 2,3"), Ok(Vector3::new(1.0, 2.0, 3.0)));
        assert!(point("1,2").is_err() && point("1,2,nan").is_err());
        assert!(direction("0,0,0").is_err());
        assert_eq!(direction("1e-320,0,0"), Ok(Vector3::x()));
        assert_eq!(direction("0,-1e300,0"), Ok(-Vector3::y()));
    }
}
