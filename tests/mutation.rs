//! Seeded mutation test of every reader of user input: valid and hostile files of
//! every format — the fuzz corpus (`fuzz/corpus/`, built by `fuzz/make_corpus.py`) and the real
//! files of `../shared/data` — are truncated, have bytes flipped, inserted and repeated, counts
//! replaced by lies and numbers by hostile ones, thousands of cases in all. No reader may panic,
//! and every error must name the file it is about. (`cargo fuzz` explores further; this runs in
//! the normal suite, with a fixed seed, in seconds.)
#![allow(clippy::unwrap_used)]

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

use pipemeasure::io::colmap::{ModelFormat, Reconstruction};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Mutations per corpus file; real files get fewer (they are larger).
const PER_SEED: usize = 200;
const PER_REAL_FILE: usize = 25;
/// The separator of a COLMAP model's three files in one fuzz input (fuzz_targets/split.rs).
const SEPARATOR: &[u8] = b"\xffPM-FILE\xff";

/// A reader under test: parses the bytes, naming them `name`; `Err` carries the message.
type Reader = fn(&str, &[u8]) -> Result<(), String>;

fn ply(name: &str, b: &[u8]) -> Result<(), String> {
    pipemeasure::io::ply::parse(Path::new(name), b)
        .map(drop)
        .map_err(|e| e.to_string())
}

fn colmap(format: ModelFormat, name: &str, b: &[u8]) -> Result<(), String> {
    let parts: Vec<&[u8]> = split(b);
    let [c, i, p] = parts[..] else {
        return Ok(()); // not three files: the fuzz target skips these too
    };
    Reconstruction::parse(Path::new(name), format, [c, i, p])
        .map(drop)
        .map_err(|e| e.to_string())
}

fn colmap_text(name: &str, b: &[u8]) -> Result<(), String> {
    colmap(ModelFormat::Text, name, b)
}

fn colmap_binary(name: &str, b: &[u8]) -> Result<(), String> {
    colmap(ModelFormat::Binary, name, b)
}

fn text<'a>(name: &str, b: &'a [u8]) -> Result<&'a str, String> {
    // The file readers read text with `read_to_string`, whose error names the file.
    std::str::from_utf8(b).map_err(|_| format!("{name}: not UTF-8"))
}

fn profile(name: &str, b: &[u8]) -> Result<(), String> {
    pipemeasure::profile::Profile::from_json(text(name, b)?, Path::new(name))
        .map(drop)
        .map_err(|e| e.to_string())
}

fn frames_sidecar(name: &str, b: &[u8]) -> Result<(), String> {
    pipemeasure::io::sidecar::FramesSidecar::parse(text(name, b)?, Path::new(name))
        .map(drop)
        .map_err(|e| e.to_string())
}

fn tls(name: &str, b: &[u8]) -> Result<(), String> {
    pipemeasure::io::tls::parse_targets(Path::new(name), text(name, b)?)
        .map(drop)
        .map_err(|e| e.to_string())
}

fn bal(name: &str, b: &[u8]) -> Result<(), String> {
    pipemeasure::io::bal::parse_bal(Path::new(name), text(name, b)?)
        .map(drop)
        .map_err(|e| e.to_string())
}

fn e57(name: &str, b: &[u8]) -> Result<(), String> {
    pipemeasure::io::e57::parse(Path::new(name), b)
        .map(drop)
        .map_err(|e| e.to_string())
}

fn observations(name: &str, b: &[u8]) -> Result<(), String> {
    pipemeasure::io::observations::DenseObservations::parse(Path::new(name), b)
        .map(drop)
        .map_err(|e| e.to_string())
}

fn vis(name: &str, b: &[u8]) -> Result<(), String> {
    let Some((head, rest)) = b.split_first_chunk::<4>() else {
        return Ok(());
    };
    pipemeasure::io::vis::parse(Path::new(name), rest, u32::from_le_bytes(*head) as usize)
        .map(drop)
        .map_err(|e| e.to_string())
}

fn frame(name: &str, b: &[u8]) -> Result<(), String> {
    let Some((_, bytes)) = b.split_first() else {
        return Ok(());
    };
    pipemeasure::io::frames::decode_frame(Path::new(name), bytes, Some((64, 48)))
        .map(drop)
        .map_err(|e| e.to_string())
}

fn split(b: &[u8]) -> Vec<&[u8]> {
    let mut parts = Vec::new();
    let mut rest = b;
    while let Some(at) = rest.windows(SEPARATOR.len()).position(|w| w == SEPARATOR) {
        parts.push(&rest[..at]);
        rest = &rest[at + SEPARATOR.len()..];
    }
    parts.push(rest);
    parts
}

/// Numbers a hostile file carries instead of plausible ones.
const HOSTILE_NUMBERS: [&str; 16] = [
    "99999999999999999999999",
    "18446744073709551616",
    "4294967296",
    "2147483648",
    "-1",
    "0",
    "-0",
    "nan",
    "inf",
    "-inf",
    "1e308",
    "-1e308",
    "1e-320",
    "1e400",
    ".",
    "0x10",
];

/// Binary values a lying count or a hostile field may hold.
const HOSTILE_WORDS: [u64; 8] = [
    0,
    1,
    u32::MAX as u64,
    1 << 31,
    u64::MAX,
    1 << 63,
    1_000_000_000_000,
    0x7ff0_0000_0000_0000, // +inf as f64
];

/// One mutation of `seed`.
fn mutate(seed: &[u8], rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    let pos = |rng: &mut ChaCha8Rng, len: usize| rng.random_range(0..=len);
    match rng.random_range(0..7) {
        // Truncation.
        0 => {
            let at = pos(rng, b.len());
            b.truncate(at);
        }
        // Byte flips.
        1 => {
            for _ in 0..rng.random_range(1..=8) {
                if !b.is_empty() {
                    let at = rng.random_range(0..b.len());
                    b[at] = rng.random();
                }
            }
        }
        // Inserted bytes.
        2 => {
            let at = pos(rng, b.len());
            let n = rng.random_range(1..=16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            b.splice(at..at, bytes);
        }
        // A slice repeated (a record twice, a header line twice).
        3 => {
            if !b.is_empty() {
                let from = rng.random_range(0..b.len());
                let to = (from + rng.random_range(1..=64)).min(b.len());
                let at = pos(rng, b.len());
                let piece = b[from..to].to_vec();
                b.splice(at..at, piece);
            }
        }
        // A lying count or hostile word in a binary field (either endian).
        4 => {
            let width = if rng.random() { 4 } else { 8 };
            if b.len() >= width {
                let at = rng.random_range(0..=b.len() - width) / width * width;
                let w = HOSTILE_WORDS[rng.random_range(0..HOSTILE_WORDS.len())];
                let bytes = if rng.random() {
                    w.to_le_bytes()
                } else {
                    w.to_be_bytes()
                };
                let bytes = if width == 4 {
                    if rng.random() {
                        &bytes[..4]
                    } else {
                        &bytes[4..]
                    }
                } else {
                    &bytes[..]
                };
                b[at..at + width].copy_from_slice(bytes);
            }
        }
        // A number in text replaced by a hostile one.
        _ => {
            let starts: Vec<usize> = (0..b.len())
                .filter(|&i| {
                    (b[i].is_ascii_digit() || b[i] == b'-' || b[i] == b'.')
                        && (i == 0 || !b[i - 1].is_ascii_alphanumeric())
                })
                .collect();
            if !starts.is_empty() {
                let s = starts[rng.random_range(0..starts.len())];
                let e = (s + 1..b.len())
                    .find(|&i| !(b[i].is_ascii_alphanumeric() || b"+-.".contains(&b[i])))
                    .unwrap_or(b.len());
                let n = HOSTILE_NUMBERS[rng.random_range(0..HOSTILE_NUMBERS.len())];
                b.splice(s..e, n.bytes());
            }
        }
    }
    b
}

/// Every file of a folder, sorted.
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .collect();
    out.sort();
    out
}

#[test]
fn mutated_files_of_every_format_never_panic_and_errors_name_the_file() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let corpus = root.join("fuzz/corpus");
    let data = root.join("../shared/data");
    let readers: [(&str, Reader); 12] = [
        ("ply_ascii", ply),
        ("ply_binary", ply),
        ("colmap_text", colmap_text),
        ("colmap_binary", colmap_binary),
        ("profile", profile),
        ("tls_targets", tls),
        ("e57", e57),
        ("bal", bal),
        ("observations", observations),
        ("vis", vis),
        ("frame", frame),
        ("frames_sidecar", frames_sidecar),
    ];
    // (reader, seed file, mutations)
    let mut seeds: Vec<(&str, Reader, PathBuf, usize)> = Vec::new();
    for (target, reader) in readers {
        for f in files(&corpus.join(target)) {
            seeds.push((target, reader, f, PER_SEED));
        }
    }
    let real: [(&str, Reader, &str); 4] = [
        (
            "ply_binary",
            ply,
            "pcl_mug/table_scene_mug_stereo_textured.ply",
        ),
        ("bal", bal, "bal/problem-49-7776-pre.txt"),
        ("e57", e57, "e57_testdata/bunnyInt19.e57"),
        ("e57", e57, "e57_testdata/bunnyDouble.e57"),
    ];
    for (target, reader, file) in real {
        seeds.push((target, reader, data.join(file), PER_REAL_FILE));
    }
    assert!(
        seeds.len() > 60,
        "{} seed files: is fuzz/corpus there?",
        seeds.len()
    );

    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (mut cases, mut errors) = (0usize, 0usize);
    let mut failures: Vec<String> = Vec::new();
    for (target, reader, path, n) in &seeds {
        let seed = std::fs::read(path).unwrap();
        let stem = path.file_name().unwrap().to_string_lossy();
        for k in 0..*n {
            let input = mutate(&seed, &mut rng);
            // A name the error must carry: the seed and the case.
            let name = format!("{target}-{stem}-case{k}");
            cases += 1;
            match catch_unwind(AssertUnwindSafe(|| reader(&name, &input))) {
                Err(_) => failures.push(format!("{name}: PANIC ({} bytes)", input.len())),
                Ok(Err(message)) => {
                    errors += 1;
                    if !message.contains(&name) {
                        failures.push(format!("{name}: error does not name the file: {message}"));
                    }
                }
                Ok(Ok(())) => {}
            }
        }
    }
    eprintln!(
        "{cases} mutated files from {} seeds: {errors} refused with an error, {} read",
        seeds.len(),
        cases - errors
    );
    assert!(cases >= 10_000, "{cases} cases");
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
