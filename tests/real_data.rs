//! Real files no one on this project made (../shared/data): pinned contents.
#![allow(clippy::unwrap_used)]

use std::path::Path;

use pipemeasure::io::ply;

const MUG: &str = "../shared/data/pcl_mug/table_scene_mug_stereo_textured.ply";

/// The PCL mug scan: a 640×480 organised stereo cloud, binary little-endian, with an empty
/// `face` element and a `camera` element after the vertices. Expected values were computed
/// independently with Python's `struct` over the raw bytes.
#[test]
fn mug_cloud_has_209280_finite_points() {
    let read = ply::read(Path::new(MUG)).unwrap();
    assert_eq!(read.vertices_in_file, 307_200);
    assert_eq!(read.skipped_non_finite, 97_920);
    assert_eq!(read.cloud.len(), 209_280);
    let first = read.cloud.points[0];
    // Vertex 6538 is the first finite one; these are its f32 coordinates widened to f64.
    assert_eq!(first.x, -0.381_909_996_271_133_4);
    assert_eq!(first.y, -0.448_199_987_411_499);
    assert_eq!(first.z, 2.025_799_989_700_317_4);
    assert_eq!(read.cloud.colors.as_ref().unwrap()[0], [67, 67, 62]);
    assert!(read.cloud.normals.is_none() && read.cloud.intensity.is_none());
    let n = read.cloud.len() as f64;
    let mean_z = read.cloud.points.iter().map(|p| p.z).sum::<f64>() / n;
    assert!(
        (mean_z - 1.264_727_422_063_287_4).abs() < 1e-12,
        "mean z {mean_z} m"
    );
}
