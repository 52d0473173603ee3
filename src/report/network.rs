//! The pipe network for people and their tools (`pipemeasure pipes`): the segments as a text
//! table and as CSV, what was refused, and the cloud coloured by segment.

use nalgebra::Vector3;

use crate::io::ply::PointCloud;
use crate::measure::network::Network;

/// The segments as a text table: nominal size, radius ± σ, the outside diameter's difference
/// from the nominal, length, axis ends, inliers, the arc covered and the RMSE.
#[must_use]
pub fn segments_table(network: &Network) -> String {
    let mut s = format!(
        "{:>3}  {:>7}  {:>5}  {:>17}  {:>8}  {:>7}  {:>28}  {:>28}  {:>7}  {:>5}  {:>5}\n",
        "id",
        "NPS",
        "DN",
        "radius mm",
        "ΔOD mm",
        "len m",
        "start",
        "end",
        "inliers",
        "arc°",
        "RMSE"
    );
    let xyz = |p: &[f64; 3]| format!("({:.3}, {:.3}, {:.3})", p[0], p[1], p[2]);
    for g in &network.segments {
        s.push_str(&format!(
            "{:>3}  {:>7}  {:>5}  {:>8.2} ± {:<6.2}  {:>+8.2}  {:>7.3}  {:>28}  {:>28}  {:>7}  {:>5.0}  {:>5.2}\n",
            g.id,
            g.nominal.nps.unwrap_or("-"),
            g.nominal.dn,
            g.radius_m * 1e3,
            g.radius_std_m * 1e3,
            g.nominal.difference_mm,
            g.length_m,
            xyz(&g.start),
            xyz(&g.end),
            g.inliers,
            g.coverage_deg,
            g.rmse_m * 1e3
        ));
    }
    s
}

/// What was refused (and why) and the planes removed, a line each.
#[must_use]
pub fn refusals_text(network: &Network) -> String {
    let mut s = String::new();
    for r in &network.refused {
        s.push_str(&format!(
            "refused: r {:.1} mm, {} points, ({:.3}, {:.3}, {:.3}) to ({:.3}, {:.3}, {:.3}): {}\n",
            r.radius_m * 1e3,
            r.inliers,
            r.start[0],
            r.start[1],
            r.start[2],
            r.end[0],
            r.end[1],
            r.end[2],
            r.refusal
        ));
    }
    for p in &network.planes {
        s.push_str(&format!(
            "removed plane: {} points, normal ({:.3}, {:.3}, {:.3}) through ({:.3}, {:.3}, {:.3})\n",
            p.points, p.normal[0], p.normal[1], p.normal[2], p.point[0], p.point[1], p.point[2]
        ));
    }
    s
}

/// The segments as CSV, one row each (`pipes --csv`): id, axis ends (m), length, radius, its σ
/// and the RMSE (m), inliers, the arc covered (°), and the nominal size (standard, NPS, DN,
/// outside diameter and the measured one's difference from it, mm).
#[must_use]
pub fn segments_csv(network: &Network) -> String {
    let mut s = String::from(
        "id,x0,y0,z0,x1,y1,z1,length_m,radius_m,radius_std_m,rmse_m,inliers,coverage_deg,standard,nps,dn,od_mm,od_difference_mm\n",
    );
    for g in &network.segments {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            g.id,
            g.start[0],
            g.start[1],
            g.start[2],
            g.end[0],
            g.end[1],
            g.end[2],
            g.length_m,
            g.radius_m,
            g.radius_std_m,
            g.rmse_m,
            g.inliers,
            g.coverage_deg,
            g.nominal.standard,
            g.nominal.nps.unwrap_or(""),
            g.nominal.dn,
            g.nominal.outside_diameter_mm,
            g.nominal.difference_mm
        ));
    }
    s
}

/// The cloud `points` (the ones the network was extracted from) with a distinct colour per
/// segment's inliers (golden-angle hues) and grey for the rest.
#[must_use]
pub fn coloured_by_segment(points: &[Vector3<f64>], network: &Network) -> PointCloud {
    let mut colors = vec![[128u8, 128, 128]; points.len()];
    for g in &network.segments {
        let h = (g.id as f64 * 137.508).rem_euclid(360.0) / 60.0;
        let x = (1.0 - (h % 2.0 - 1.0).abs()) * 255.0;
        let c = match h as u32 {
            0 => [255.0, x, 0.0],
            1 => [x, 255.0, 0.0],
            2 => [0.0, 255.0, x],
            3 => [0.0, x, 255.0],
            4 => [x, 0.0, 255.0],
            _ => [255.0, 0.0, x],
        };
        for &k in &g.inlier_indices {
            if let Some(slot) = colors.get_mut(k) {
                *slot = c.map(|v| v as u8);
            }
        }
    }
    PointCloud {
        points: points.iter().map(|p| (*p).into()).collect(),
        colors: Some(colors),
        ..Default::default()
    }
}
