//! Reads a point cloud and prints what was read and how long it took: the PLY reader's peak
//! memory is measured with it (`/usr/bin/time -v cargo run --release --example read_cloud --
//! FILE [--points]`; README "Performance").
//!
//! `--points` reads the coordinates only (`ply::read_points`, what measuring reads).

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().ok_or("usage: read_cloud FILE [--points]")?);
    let points_only = args.next().as_deref() == Some("--points");
    let start = std::time::Instant::now();
    let read = if points_only {
        pipemeasure::io::ply::read_points(&path)?
    } else {
        pipemeasure::io::ply::read(&path)?
    };
    let seconds = start.elapsed().as_secs_f64();
    let bytes = std::fs::metadata(&path)?.len() as f64;
    println!(
        "{}: {} vertices, {} finite, normals {}, colours {}; {seconds:.2} s, {:.0} MB/s",
        path.display(),
        read.vertices_in_file,
        read.cloud.len(),
        read.cloud.normals.is_some(),
        read.cloud.colors.is_some(),
        bytes / seconds / 1e6
    );
    Ok(())
}
