//! Nominal pipe sizes: the closest standard outside diameter to a measured one.
//!
//! - Carbon steel: ASME B36.10M (NPS with its DN from ISO 6708; the outside diameters of
//!   EN 10220's series 1 are the same to 0.1 mm).
//! - Stainless steel: ASME B36.19M, whose outside diameters are B36.10M's.
//! - Ductile iron: AWWA C151/A21.51 (North America, nominal inches) and ISO 2531 / EN 545
//!   (DN), whose outside diameters differ from steel's (a 6-inch ductile-iron pipe is 175.3 mm,
//!   a 6-inch steel pipe 168.3 mm).

use serde::Serialize;

/// A pipe material whose standard sizes are known.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum PipeMaterial {
    /// Carbon steel, ASME B36.10M.
    #[default]
    Steel,
    /// Stainless steel, ASME B36.19M.
    Stainless,
    /// Ductile iron, AWWA C151.
    DuctileIron,
    /// Ductile iron, ISO 2531.
    DuctileIronIso,
}

/// AWWA C151 ductile iron: (nominal size in inches, the DN ISO 6708 gives it, outside diameter
/// mm: the standard's inches × 25.4), 3 to 64 inches.
const AWWA_C151: [(&str, u32, f64); 18] = [
    ("3", 80, 100.584),
    ("4", 100, 121.92),
    ("6", 150, 175.26),
    ("8", 200, 229.87),
    ("10", 250, 281.94),
    ("12", 300, 335.28),
    ("14", 350, 388.62),
    ("16", 400, 441.96),
    ("18", 450, 495.3),
    ("20", 500, 548.64),
    ("24", 600, 655.32),
    ("30", 750, 812.8),
    ("36", 900, 972.82),
    ("42", 1050, 1130.3),
    ("48", 1200, 1290.32),
    ("54", 1350, 1461.77),
    ("60", 1500, 1564.64),
    ("64", 1600, 1676.4),
];

/// ASME B36.10M: (NPS, DN, outside diameter mm), NPS 1/8 to 48.
const ASME_B36_10M: [(&str, u32, f64); 33] = [
    ("1/8", 6, 10.3),
    ("1/4", 8, 13.7),
    ("3/8", 10, 17.1),
    ("1/2", 15, 21.3),
    ("3/4", 20, 26.7),
    ("1", 25, 33.4),
    ("1 1/4", 32, 42.2),
    ("1 1/2", 40, 48.3),
    ("2", 50, 60.3),
    ("2 1/2", 65, 73.0),
    ("3", 80, 88.9),
    ("3 1/2", 90, 101.6),
    ("4", 100, 114.3),
    ("5", 125, 141.3),
    ("6", 150, 168.3),
    ("8", 200, 219.1),
    ("10", 250, 273.0),
    ("12", 300, 323.8),
    ("14", 350, 355.6),
    ("16", 400, 406.4),
    ("18", 450, 457.2),
    ("20", 500, 508.0),
    ("22", 550, 558.8),
    ("24", 600, 609.6),
    ("26", 650, 660.4),
    ("28", 700, 711.2),
    ("30", 750, 762.0),
    ("32", 800, 812.8),
    ("34", 850, 863.6),
    ("36", 900, 914.4),
    ("40", 1000, 1016.0),
    ("42", 1050, 1066.8),
    ("48", 1200, 1219.2),
];

/// ISO 2531 ductile iron: (DN, outside diameter mm), DN 40 to 1200.
const ISO_2531: [(u32, f64); 20] = [
    (40, 56.0),
    (50, 66.0),
    (60, 77.0),
    (65, 82.0),
    (80, 98.0),
    (100, 118.0),
    (125, 144.0),
    (150, 170.0),
    (200, 222.0),
    (250, 274.0),
    (300, 326.0),
    (350, 378.0),
    (400, 429.0),
    (450, 480.0),
    (500, 532.0),
    (600, 635.0),
    (700, 738.0),
    (800, 842.0),
    (900, 945.0),
    (1000, 1048.0),
];

/// The standard size closest to a measured outside diameter.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NominalSize {
    /// The table it comes from (`ASME B36.10M`, `ASME B36.19M`, `ISO 2531`).
    pub standard: &'static str,
    /// NPS (`"4"`), for the ASME tables.
    pub nps: Option<&'static str>,
    /// DN.
    pub dn: u32,
    /// The standard outside diameter (mm).
    pub outside_diameter_mm: f64,
    /// Measured minus standard outside diameter (mm).
    pub difference_mm: f64,
}

/// The standard size of `material` whose outside diameter is closest to `measured_od_mm`.
#[must_use]
pub fn nominal_size(measured_od_mm: f64, material: PipeMaterial) -> NominalSize {
    let closest = |od: f64| (od - measured_od_mm).abs();
    match material {
        PipeMaterial::Steel | PipeMaterial::Stainless | PipeMaterial::DuctileIron => {
            let (table, standard): (&[(&'static str, u32, f64)], _) = match material {
                PipeMaterial::Steel => (&ASME_B36_10M, "ASME B36.10M"),
                PipeMaterial::Stainless => (&ASME_B36_10M, "ASME B36.19M"),
                _ => (&AWWA_C151, "AWWA C151"),
            };
            let (nps, dn, od) = table
                .iter()
                .copied()
                .min_by(|a, b| closest(a.2).total_cmp(&closest(b.2)))
                .unwrap_or(table[0]);
            NominalSize {
                standard,
                nps: Some(nps),
                dn,
                outside_diameter_mm: od,
                difference_mm: measured_od_mm - od,
            }
        }
        PipeMaterial::DuctileIronIso => {
            let (dn, od) = ISO_2531
                .iter()
                .copied()
                .min_by(|a, b| closest(a.1).total_cmp(&closest(b.1)))
                .unwrap_or(ISO_2531[0]);
            NominalSize {
                standard: "ISO 2531",
                nps: None,
                dn,
                outside_diameter_mm: od,
                difference_mm: measured_od_mm - od,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The published outside diameters map to their own sizes, and a measurement between two
    /// sizes to the nearer one with the signed difference.
    #[test]
    fn the_closest_standard_size_is_found() {
        let s = nominal_size(168.3, PipeMaterial::Steel);
        assert_eq!((s.nps, s.dn), (Some("6"), 150));
        assert_eq!(s.difference_mm, 0.0);
        // The pump-room scan's pipes, 88.06 mm and 87.40 mm radius: 6-inch ductile
        // iron (175.26 mm), 7 mm wider than 6-inch steel.
        for r in [88.06, 87.40] {
            let s = nominal_size(2.0 * r, PipeMaterial::DuctileIron);
            assert_eq!((s.nps, s.standard), (Some("6"), "AWWA C151"), "{r}");
            assert!((s.difference_mm - (2.0 * r - 175.26)).abs() < 1e-9);
            let steel = nominal_size(2.0 * r, PipeMaterial::Steel);
            assert!(steel.difference_mm > 6.0, "{steel:?}");
        }
        let s = nominal_size(100.0, PipeMaterial::Stainless);
        assert_eq!((s.nps, s.standard), (Some("3 1/2"), "ASME B36.19M"));
        assert!((s.difference_mm - (100.0 - 101.6)).abs() < 1e-12);
        let s = nominal_size(171.0, PipeMaterial::DuctileIronIso);
        assert_eq!((s.nps, s.dn, s.outside_diameter_mm), (None, 150, 170.0));
    }
}
