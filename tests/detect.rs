//! Ellipse detection: accuracy on simulated frames, every kind of image without panicking, and
//! the `detect` command.
#![allow(clippy::unwrap_used)]

mod common;

use image::{DynamicImage, ImageBuffer, Luma, LumaA, Rgb, Rgba};
use pipemeasure::detect::{DetectConfig, Detector, detect_in_frame};
use pipemeasure::experiments::detection::{EvalConfig, evaluate};
use pipemeasure::sim::lab::LabConfig;
use pipemeasure::sim::simulate::SimulateOptions;

/// The acceptance figures on a short simulated lab at 960×540 (default noise and blur):
/// recall and precision ≥ 99.5 %, centre RMS ≤ 0.05 px and 99th percentile ≤ 0.15 px for
/// targets with semi-minor axis ≥ 4 px. (The README reports the full 4K sequences.)
#[test]
fn simulated_lab_meets_the_detection_acceptance_figures() {
    let cfg = EvalConfig {
        options: SimulateOptions {
            width: 960,
            height: 540,
            seed: 41,
            ..Default::default()
        },
        lab: LabConfig {
            frames: 6,
            ..Default::default()
        },
        detect: DetectConfig::default(),
        min_semi_minor_px: 4.0,
    };
    let r = evaluate(&cfg).unwrap();
    println!("{r:?}");
    assert!(r.required > 100, "{} targets to find", r.required);
    assert!(r.recall >= 0.995, "recall {}", r.recall);
    assert!(
        r.precision >= 0.995,
        "precision {} ({} false)",
        r.precision,
        r.false_positives
    );
    assert!(r.centre_rms_px <= 0.05, "centre RMS {} px", r.centre_rms_px);
    assert!(r.centre_p99_px <= 0.15, "centre p99 {} px", r.centre_p99_px);
}

/// A dark disc rendered 4×4 supersampled with the conic of its edge known exactly.
fn disc_frame(w: u32, h: u32, cx: f64, cy: f64, r: f64) -> ImageBuffer<Luma<u8>, Vec<u8>> {
    ImageBuffer::from_fn(w, h, |x, y| {
        let mut inside = 0;
        for sy in 0..4 {
            for sx in 0..4 {
                let (u, v) = (
                    f64::from(x) + (f64::from(sx) + 0.5) / 4.0,
                    f64::from(y) + (f64::from(sy) + 0.5) / 4.0,
                );
                if (u - cx).powi(2) + (v - cy).powi(2) <= r * r {
                    inside += 1;
                }
            }
        }
        Luma([(210 - inside * 180 / 16) as u8])
    })
}

#[test]
fn every_kind_of_image_is_handled_without_panic() {
    let config = DetectConfig::default();
    let mut cases: Vec<(&str, DynamicImage)> = vec![
        ("1x1", DynamicImage::ImageLuma8(ImageBuffer::new(1, 1))),
        ("2x3", DynamicImage::ImageRgb8(ImageBuffer::new(2, 3))),
        ("15x15", DynamicImage::ImageRgba8(ImageBuffer::new(15, 15))),
        (
            "blank",
            DynamicImage::ImageRgb8(ImageBuffer::from_pixel(400, 300, Rgb([0, 0, 0]))),
        ),
        (
            "saturated",
            DynamicImage::ImageRgb8(ImageBuffer::from_pixel(400, 300, Rgb([255, 255, 255]))),
        ),
        (
            "huge blank",
            DynamicImage::ImageLuma8(ImageBuffer::from_pixel(6000, 4000, Luma([128]))),
        ),
    ];
    // Pure noise: whatever is reported, nothing panics.
    let mut seed = 1u64;
    cases.push((
        "noise",
        DynamicImage::ImageLuma8(ImageBuffer::from_fn(300, 200, |_, _| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            Luma([(seed >> 56) as u8])
        })),
    ));
    for (name, img) in &cases {
        let d = detect_in_frame(img, &config).unwrap();
        assert_eq!(
            (d.width, d.height),
            (img.width() as usize, img.height() as usize),
            "{name}"
        );
        if name.contains("blank") || *name == "saturated" || name.contains('x') {
            assert!(
                d.ellipses.is_empty(),
                "{name}: {} ellipses",
                d.ellipses.len()
            );
        }
    }
    // One disc in every pixel format: found, at the right place.
    let grey = disc_frame(120, 90, 60.3, 44.8, 20.0);
    let formats: Vec<(&str, DynamicImage)> = vec![
        ("grey8", DynamicImage::ImageLuma8(grey.clone())),
        (
            "greyA8",
            DynamicImage::ImageLumaA8(ImageBuffer::from_fn(120, 90, |x, y| {
                LumaA([grey.get_pixel(x, y).0[0], 255])
            })),
        ),
        (
            "rgb8",
            DynamicImage::ImageRgb8(ImageBuffer::from_fn(120, 90, |x, y| {
                let v = grey.get_pixel(x, y).0[0];
                Rgb([v, v, v])
            })),
        ),
        (
            "rgba8",
            DynamicImage::ImageRgba8(ImageBuffer::from_fn(120, 90, |x, y| {
                let v = grey.get_pixel(x, y).0[0];
                Rgba([v, v, v, 255])
            })),
        ),
        (
            "grey16",
            DynamicImage::ImageLuma16(ImageBuffer::from_fn(120, 90, |x, y| {
                Luma([u16::from(grey.get_pixel(x, y).0[0]) * 257])
            })),
        ),
        (
            "rgb16",
            DynamicImage::ImageRgb16(ImageBuffer::from_fn(120, 90, |x, y| {
                let v = u16::from(grey.get_pixel(x, y).0[0]) * 257;
                Rgb([v, v, v])
            })),
        ),
        (
            "rgb32f",
            DynamicImage::ImageRgb32F(ImageBuffer::from_fn(120, 90, |x, y| {
                let v = f32::from(grey.get_pixel(x, y).0[0]) / 255.0;
                Rgb([v, v, v])
            })),
        ),
    ];
    for (name, img) in &formats {
        let d = detect_in_frame(img, &config).unwrap();
        assert_eq!(d.ellipses.len(), 1, "{name}");
        let e = &d.ellipses[0];
        // 4×4 supersampling quantises the edge coverage to 1/16: ~0.01 px on the centre.
        assert!(
            (e.cx - 60.3).abs() < 0.02 && (e.cy - 44.8).abs() < 0.02,
            "{name}: {e:?}"
        );
        assert!(
            (e.a - 20.0).abs() < 0.1 && (e.b - 20.0).abs() < 0.1,
            "{name}: {e:?}"
        );
    }
}

#[test]
fn palette_png_is_decoded_and_its_disc_found() {
    let img = image::open("tests/fixtures/palette_disc.png").unwrap();
    let d = Detector::new(DetectConfig::default()).unwrap().detect(&img);
    assert_eq!(d.ellipses.len(), 1);
    let e = &d.ellipses[0];
    // 4×4 coverage quantised to 17 palette levels and no blur: centre within 0.03 px.
    assert!(
        (e.cx - 32.5).abs() < 0.03 && (e.cy - 30.0).abs() < 0.03,
        "{e:?}"
    );
    assert!((e.a - 14.0).abs() < 0.1, "{e:?}");
}

#[test]
fn targets_cut_by_the_border_or_occluded_are_rejected() {
    // A disc whose edge leaves the frame, and one half-covered by a bright bar.
    let mut img = disc_frame(200, 120, 12.0, 60.0, 20.0);
    let other = disc_frame(200, 120, 130.0, 60.0, 25.0);
    for (x, y, p) in img.enumerate_pixels_mut() {
        let v = other.get_pixel(x, y).0[0];
        if x >= 60 {
            p.0[0] = v;
        }
        if (125..200).contains(&x) && (40..52).contains(&y) {
            p.0[0] = 240; // occluder across the second disc
        }
    }
    let d = detect_in_frame(&DynamicImage::ImageLuma8(img), &DetectConfig::default()).unwrap();
    assert!(d.ellipses.is_empty(), "{:?}", d.ellipses);
}

#[test]
fn detect_command_prints_json_lines_and_writes_overlays() {
    let dir = tempfile::tempdir().unwrap();
    let f1 = dir.path().join("a.png");
    DynamicImage::ImageLuma8(disc_frame(160, 120, 70.2, 55.6, 18.0))
        .save(&f1)
        .unwrap();
    let f2 = dir.path().join("b.png");
    DynamicImage::ImageLuma8(ImageBuffer::from_pixel(50, 50, Luma([10])))
        .save(&f2)
        .unwrap();
    let (code, stdout, stderr) = common::pipemeasure(
        dir.path(),
        &["detect", "--json", "--overlay", "ov", "a.png", "b.png"],
        &[],
    );
    assert_eq!(code, 0, "{stderr}");
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0]["frame"], "a.png");
    assert_eq!(lines[0]["width"], 160);
    let e = &lines[0]["ellipses"][0];
    assert!(
        (e["cx"].as_f64().unwrap() - 70.2).abs() < 0.02
            && (e["cy"].as_f64().unwrap() - 55.6).abs() < 0.02,
        "{e}"
    );
    assert!(e["a"].as_f64().unwrap() >= e["b"].as_f64().unwrap());
    assert_eq!(lines[1]["ellipses"].as_array().unwrap().len(), 0);
    assert!(dir.path().join("ov/a.png").is_file() && dir.path().join("ov/b.png").is_file());

    std::fs::write(dir.path().join("bad.png"), b"not a png").unwrap();
    let (code, _, stderr) = common::pipemeasure(dir.path(), &["detect", "bad.png"], &[]);
    assert_eq!(code, 1);
    assert!(stderr.contains("bad.png"), "{stderr}");
}
