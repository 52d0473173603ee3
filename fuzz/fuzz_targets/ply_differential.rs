//! The differential check of the PLY targets: the reader and its streamed twin on the same
//! bytes must give the same points (bit for bit), counts and verdict.

pub fn check(data: &[u8]) {
    let path = std::path::Path::new("fuzz.ply");
    let whole = pipemeasure::io::ply::parse(path, data);
    let mut points = Vec::new();
    let streamed = pipemeasure::io::ply::parse_streamed(path, data, 7, &mut |c| {
        points.extend_from_slice(c)
    });
    match (whole, streamed) {
        (Ok(w), Ok(s)) => {
            assert_eq!(w.vertices_in_file, s.vertices_in_file);
            assert_eq!(w.skipped_non_finite, s.skipped_non_finite);
            assert_eq!(w.cloud.points.len(), points.len());
            for (a, b) in w.cloud.points.iter().zip(&points) {
                assert_eq!(a.coords.map(f64::to_bits), b.coords.map(f64::to_bits));
            }
        }
        (Err(_), Err(_)) => {}
        (w, s) => panic!("whole {:?}, streamed {:?}", w.is_ok(), s.is_ok()),
    }
}
