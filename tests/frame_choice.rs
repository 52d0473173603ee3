//! Frame choice from video. A simulated hand-held lab video at 25 fps
//! whose motion varies over time (3–9 °/s at the stations, a pause at each viewpoint), encoded
//! by ffmpeg; the frames chosen per second by their measured apparent motion and sharpness are
//! judged by the simulator's truth (each video frame's angular speed in `video/motion.json`)
//! against plain 1 fps extraction. Needs ffmpeg (fails, not skips, under CI).

mod common;

use common::pipemeasure;
use pipemeasure::sim::video::VideoMotion;
use pipemeasure::video::{FrameChoice, choose, extract_frames, measure, probe};

fn ffmpeg_available() -> bool {
    common::program_available("ffmpeg", "-version", "apt-get install -y ffmpeg")
}

#[test]
fn the_chosen_frames_move_at_most_half_as_fast_as_plain_extraction() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let lab = dir.path().join("lab");
    common::simulate(
        dir.path(),
        lab.to_str().unwrap(),
        &[
            "lab",
            "--like",
            "p30",
            "--width",
            "320",
            "--frames",
            "8",
            "--video",
            "--fps",
            "25",
            "--video-width",
            "480",
        ],
    );
    let motion: VideoMotion =
        serde_json::from_str(&std::fs::read_to_string(lab.join("video/motion.json")).unwrap())
            .unwrap();
    let video = lab.join("video.mp4");
    let info = probe(&video).unwrap();
    assert_eq!((info.width, info.height), (480, 270));
    assert!((info.fps - 25.0).abs() < 1e-9);
    let measures = measure(&video, &info, &|_| {}).unwrap();
    assert_eq!(measures.len(), motion.frames.len());

    let speed = |ks: &[usize]| {
        ks.iter()
            .map(|&k| motion.frames[k].angular_speed_deg_s)
            .sum::<f64>()
            / ks.len() as f64
    };
    let chosen = choose(&measures, info.fps, FrameChoice::PerSecond(1));
    let plain = choose(&measures, info.fps, FrameChoice::EveryFrameAt(1.0));
    // The video runs from the first station to the last, 7 s (176 frames): seven whole seconds,
    // and an eighth window holding only the last frame, which has no next neighbour. Plain
    // extraction takes the frame next to each station, the last one's previous neighbour.
    assert_eq!(measures.len(), 176);
    assert_eq!(chosen.len(), 7);
    assert_eq!(plain.len(), 8);
    let (s_chosen, s_plain) = (speed(&chosen), speed(&plain));
    eprintln!(
        "mean angular speed: chosen {s_chosen:.2} °/s, plain 1 fps {s_plain:.2} °/s (frames {chosen:?} vs {plain:?})"
    );
    assert!(
        s_chosen <= 0.5 * s_plain,
        "chosen {s_chosen:.2} °/s against plain {s_plain:.2} °/s"
    );
    // The measured motion orders the frames as the truth does: over all frames, the rank
    // correlation of the measured motion with the true angular speed is strong.
    let measured: Vec<f64> = measures.iter().map(|m| m.motion_px.unwrap()).collect();
    let truth: Vec<f64> = motion
        .frames
        .iter()
        .map(|f| f.angular_speed_deg_s)
        .collect();
    let rho = spearman(&measured, &truth);
    eprintln!("rank correlation of measured motion and true angular speed: {rho:.3}");
    assert!(rho > 0.8, "{rho}");

    // Written as calibrate --video writes them: the chosen frames, their neighbours, the sidecar.
    let out = dir.path().join("chosen");
    let extraction =
        extract_frames(&video, &out, FrameChoice::PerSecond(1), true, &|_, _| {}).unwrap();
    assert_eq!(extraction.sidecar.frames.len(), 7);
    for entry in &extraction.sidecar.frames {
        for name in std::iter::once(&entry.name).chain(entry.neighbours.iter().map(|n| &n.name)) {
            let img = image::open(out.join(name)).unwrap();
            assert_eq!((img.width(), img.height()), (480, 270), "{name}");
        }
    }
    let read = pipemeasure::io::sidecar::FramesSidecar::read(&out.join("frames.json")).unwrap();
    assert_eq!(read, extraction.sidecar);
    // A second extraction into the same folder is refused, and the frames stay.
    let again = extract_frames(&video, &out, FrameChoice::PerSecond(1), true, &|_, _| {});
    assert!(again.unwrap_err().to_string().contains("already holds"));
    assert!(out.join("frame_0007.png").is_file());

    // A site's video through `pipemeasure frames`: the same choice, no neighbours (COLMAP
    // reads the folder as it is).
    let site = dir.path().join("site_frames");
    let (code, _, err) = pipemeasure(
        dir.path(),
        &[
            "frames",
            video.to_str().unwrap(),
            "--out",
            site.to_str().unwrap(),
            "--quiet",
        ],
        &[],
    );
    assert_eq!(code, 0, "{err}");
    let sidecar = pipemeasure::io::sidecar::FramesSidecar::read(&site.join("frames.json")).unwrap();
    let names: Vec<&String> = sidecar.frames.iter().map(|f| &f.name).collect();
    let expected: Vec<&String> = extraction.sidecar.frames.iter().map(|f| &f.name).collect();
    assert_eq!(names, expected);
    assert!(sidecar.frames.iter().all(|f| f.neighbours.is_empty()));
    assert!(!site.join("neighbours").exists());
    for (a, b) in sidecar.frames.iter().zip(&extraction.sidecar.frames) {
        assert_eq!(a.time_s, b.time_s);
        let (x, y) = (
            image::open(site.join(&a.name)).unwrap(),
            image::open(out.join(&b.name)).unwrap(),
        );
        assert_eq!(x.as_bytes(), y.as_bytes(), "{}", a.name);
    }
    // A missing video: exit 1 naming it.
    let (code, _, err) = pipemeasure(dir.path(), &["frames", "missing.mp4"], &[]);
    assert_eq!(code, 1);
    assert!(err.contains("missing.mp4"), "{err}");
}

#[test]
fn a_file_that_is_not_a_video_is_refused_with_its_name() {
    if !ffmpeg_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let fake = dir.path().join("lab.mp4");
    std::fs::write(&fake, b"not a video at all").unwrap();
    let err = probe(&fake).unwrap_err().to_string();
    assert!(err.contains("lab.mp4"), "{err}");
    let (code, _, err) = pipemeasure(
        dir.path(),
        &[
            "calibrate",
            "--device",
            "x",
            "--video",
            fake.to_str().unwrap(),
            "--out",
            dir.path().join("x.json").to_str().unwrap(),
        ],
        &[],
    );
    assert_ne!(code, 0);
    assert!(err.contains("lab.mp4"), "{err}");
    assert!(!dir.path().join("x.json").exists());
    assert!(!dir.path().join("lab_frames").exists());
}

/// Spearman's rank correlation.
fn spearman(a: &[f64], b: &[f64]) -> f64 {
    let rank = |v: &[f64]| {
        let mut idx: Vec<usize> = (0..v.len()).collect();
        idx.sort_by(|&i, &j| v[i].total_cmp(&v[j]));
        let mut r = vec![0.0; v.len()];
        for (pos, &i) in idx.iter().enumerate() {
            r[i] = pos as f64;
        }
        r
    };
    let (ra, rb) = (rank(a), rank(b));
    let n = a.len() as f64;
    let mean = (n - 1.0) / 2.0;
    let cov: f64 = ra
        .iter()
        .zip(&rb)
        .map(|(x, y)| (x - mean) * (y - mean))
        .sum();
    let var: f64 = ra.iter().map(|x| (x - mean) * (x - mean)).sum();
    cov / var
}
