//! The PLY reader on a large binary file: a dense cloud as COLMAP's fusion writes it (float
//! x y z, float nx ny nz, uchar red green blue: 27 bytes per point), 1 GiB by default
//! (`PM_PLY_BENCH_MB` sets another size), made once in the target's temporary folder. Throughput
//! of `ply::read` (every attribute kept) and `ply::read_points` (coordinates only, what
//! measuring reads). Peak memory: `examples/read_cloud.rs` under `/usr/bin/time -v`.
#![allow(missing_docs, clippy::unwrap_used)]

use std::io::Write;
use std::path::{Path, PathBuf};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Bytes per vertex of the bench file.
const VERTEX_BYTES: u64 = 27;

/// The bench file of about `mb` MiB, written once.
fn bench_file(mb: u64) -> PathBuf {
    let path = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("bench-{mb}mib.ply"));
    if path.is_file() {
        return path;
    }
    let n = mb * (1 << 20) / VERTEX_BYTES;
    let tmp = path.with_extension("partial");
    let mut w = std::io::BufWriter::with_capacity(1 << 22, std::fs::File::create(&tmp).unwrap());
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut record = [0u8; VERTEX_BYTES as usize];
    for _ in 0..n {
        for k in 0..6 {
            let v: f32 = rng.random_range(-10.0..10.0);
            record[4 * k..4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
        record[24..].copy_from_slice(&[rng.random(), rng.random(), rng.random()]);
        w.write_all(&record).unwrap();
    }
    w.into_inner().unwrap().sync_all().unwrap();
    std::fs::rename(&tmp, &path).unwrap();
    path
}

fn reader(c: &mut Criterion) {
    let mb = std::env::var("PM_PLY_BENCH_MB")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1024);
    let path = bench_file(mb);
    let bytes = std::fs::metadata(&path).unwrap().len();
    let mut group = c.benchmark_group("ply/read");
    group.sample_size(10);
    group.throughput(Throughput::Bytes(bytes));
    group.bench_function(format!("{mb} MiB, every attribute"), |b| {
        b.iter(|| pipemeasure::io::ply::read(&path).unwrap().cloud.len());
    });
    group.bench_function(format!("{mb} MiB, coordinates only"), |b| {
        b.iter(|| {
            pipemeasure::io::ply::read_points(&path)
                .unwrap()
                .cloud
                .len()
        });
    });
    group.finish();
}

criterion_group!(benches, reader);
criterion_main!(benches);
