//! Filming a scene as a phone video: the stations become a continuous hand-held trajectory
//! ([`super::trajectory`]), and frames are rendered at their times by a moving rolling-shutter
//! camera ([`super::render::render_radiance_moving`]) with motion blur and, optionally, focus
//! breathing.
//!
//! ```text
//! OUT/frames/frame_0001.png …            the 1 fps extraction: frame k at time (k − 1)·interval
//! OUT/frames/neighbours/frame_0001-1.png  with `neighbours`: the video frames 1/fps before
//! OUT/frames/neighbours/frame_0001+1.png  and after each extracted frame
//! OUT/frames/frames.json                  schema pipemeasure.frames/1: per frame its time and
//!                                         neighbours ({"name","dt_s"}, names relative to frames/)
//! OUT/video/frame_00001.png …             with `full_rate_width`: every video frame, small
//! OUT/video/motion.json                   schema pipemeasure.video/1: per video frame its time,
//!                                         ω, ν and speeds
//! OUT/video.mp4                           the same frames encoded by ffmpeg (when on the PATH)
//! ```
//!
//! With `stream_full_rate` the full-rate frames are piped to ffmpeg as raw RGB in their order
//! and no PNG is written (a 90 s 4K30 video would be some 50 GB of PNG): `video/` then holds
//! `motion.json` only, and ffmpeg is required.
//!
//! Focus breathing: the focus distance of a frame is the harmonic mean of the depths seen by
//! nine rays about the image centre (±5 % of the normalised image) at the frame time, and the
//! frame's principal distance `c·(1 + β·(1/d − 1/d_ref))` ([`super::devices::breathing_factor`])
//! holds over its readout (autofocus moves the lens between frames, not within one).

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::{Point3, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::devices::{FOCUS_REFERENCE_M, breathing_factor, preset};
use super::lab::Station;
use super::options::{SimError, SimulateOptions};
use super::render::{Frame, MovingView, RayGrid, RenderConfig, render_frame_moving};
use super::scene::Scene;
use super::shutter::{PoseTable, Shutter, project_rolling_shutter};
use super::trajectory::Trajectory;
use super::truth::{
    FrameMotion, FullRateTruth, Orientation, TruthFrame, VideoTruth, frame_truth_moving,
};
pub use super::video_config::VideoConfig;
use crate::camera::BrownCamera;
use crate::io::WriteError;
use crate::io::atomic::write_bytes_atomic;

pub use crate::io::sidecar::{FRAMES_SCHEMA, FramesEntry, FramesSidecar, NeighbourEntry};
/// The full-rate video's encoding (both routes, PNG or streamed, so they give the same video):
/// H.264, quality CRF 18, yuv420p.
const X264: [&str; 6] = ["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "18"];
/// How to get ffmpeg, for the messages that miss it.
const FFMPEG_INSTALL: &str = "Debian/Ubuntu: apt-get install ffmpeg";
/// Schema tag of the full-rate video's `video/motion.json`.
pub const VIDEO_MOTION_SCHEMA: &str = "pipemeasure.video/1";
/// Noise-seed frame numbers of neighbours start here (main frames use their index).
const NEIGHBOUR_FRAME_IDS: u64 = 1_000_000;
/// Noise-seed frame numbers of full-rate video frames start here.
const VIDEO_FRAME_IDS: u64 = 2_000_000;

/// One video frame in `video/motion.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VideoFrameMotion {
    /// File name in `video/`.
    pub name: String,
    /// Time (s).
    pub time_s: f64,
    /// ω at that time, camera frame (rad/s).
    pub angular_velocity: [f64; 3],
    /// ν at that time, camera frame (m/s).
    pub linear_velocity: [f64; 3],
    /// |ω| (°/s).
    pub angular_speed_deg_s: f64,
    /// |ν| (m/s).
    pub linear_speed_m_s: f64,
    /// The extracted frame taken at this time, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extracted: Option<String>,
}

/// `video/motion.json` (schema [`VIDEO_MOTION_SCHEMA`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VideoMotion {
    /// Always [`VIDEO_MOTION_SCHEMA`].
    pub schema: String,
    /// Frames per second.
    pub frame_rate: f64,
    /// Frame width (px).
    pub width: u32,
    /// Frame height (px).
    pub height: u32,
    /// Readout time (s).
    pub readout_s: f64,
    /// Exposure time (s).
    pub exposure_s: f64,
    /// Every frame.
    pub frames: Vec<VideoFrameMotion>,
}

/// One frame to take.
#[derive(Clone, Debug)]
struct Shot {
    /// File name relative to its folder.
    name: String,
    time_s: f64,
    /// Frame number for the noise seed.
    noise_id: u64,
    image_id: u32,
    orientation: Orientation,
}

/// The camera of a frame focused at `factor` (c, b1, b2 scaled).
fn breathing_camera(camera: &BrownCamera, factor: f64) -> BrownCamera {
    let mut c = *camera;
    c.intrinsics.c *= factor;
    c.intrinsics.b1 *= factor;
    c.intrinsics.b2 *= factor;
    c
}

/// A scene being filmed: the trajectory through its stations and the camera's settings.
pub struct Filming<'a> {
    scene: &'a Scene,
    camera: BrownCamera,
    options: &'a SimulateOptions,
    config: VideoConfig,
    trajectory: Trajectory,
    readout_s: f64,
    breathing_m: f64,
    gain: f64,
    orientations: Vec<Orientation>,
    done: AtomicUsize,
}

impl<'a> Filming<'a> {
    /// Prepares to film `scene` along `stations` with the video options of `options`.
    ///
    /// # Errors
    ///
    /// [`SimError`] for bad options (no video options, unknown device, bad values).
    pub fn new(
        scene: &'a Scene,
        camera: &BrownCamera,
        stations: &[Station],
        gain: f64,
        options: &'a SimulateOptions,
    ) -> Result<Self, SimError> {
        let config = options.video.clone().ok_or(SimError::Option {
            field: "video",
            reason: "no video options".into(),
        })?;
        config.validate()?;
        let device = preset(&options.device).ok_or_else(|| SimError::UnknownDevice {
            name: options.device.clone(),
        })?;
        let poses: Vec<_> = stations.iter().map(|s| s.cam_from_world).collect();
        let trajectory =
            Trajectory::through(&poses, config.interval_s, &config.motion, options.seed);
        Ok(Filming {
            scene,
            camera: *camera,
            options,
            readout_s: config.readout_s.unwrap_or(device.readout_s),
            breathing_m: if config.focus_breathing {
                device.focus_breathing_m
            } else {
                0.0
            },
            config,
            trajectory,
            gain,
            orientations: stations.iter().map(|s| s.orientation).collect(),
            done: AtomicUsize::new(0),
        })
    }

    /// The trajectory.
    #[must_use]
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }

    /// The stations at the extracted frames' times (the poses of the trajectory there: the
    /// SfM stand-in's and the dense cloud's "true" poses).
    #[must_use]
    pub fn stations(&self) -> Vec<Station> {
        self.orientations
            .iter()
            .enumerate()
            .map(|(k, &orientation)| Station {
                cam_from_world: self.trajectory.cam_from_world(self.main_time(k)),
                orientation,
            })
            .collect()
    }

    fn main_time(&self, k: usize) -> f64 {
        k as f64 * self.config.interval_s
    }

    /// The timing of a frame at `time_s`.
    #[must_use]
    pub fn shutter(&self, time_s: f64) -> Shutter {
        Shutter {
            time_s,
            readout_s: self.readout_s,
            exposure_s: self.config.exposure_s,
        }
    }

    /// The factor of the principal distance of a frame at `time_s` (1 without breathing).
    #[must_use]
    pub fn breathing(&self, time_s: f64) -> f64 {
        if self.breathing_m == 0.0 {
            return 1.0;
        }
        let pose = self.trajectory.cam_from_world(time_s);
        let origin = crate::geometry::pose::camera_centre(&pose);
        let world_from_cam = pose.rotation.inverse();
        let mut inverse_depths = Vec::with_capacity(9);
        for x in [-0.05, 0.0, 0.05] {
            for y in [-0.05, 0.0, 0.05] {
                // The ray's camera z component is 1: the hit parameter is the depth.
                let dir = world_from_cam * Vector3::new(x, y, 1.0);
                if let Some(hit) = self.scene.intersect(&origin, &dir) {
                    inverse_depths.push(1.0 / hit.t);
                }
            }
        }
        if inverse_depths.is_empty() {
            return 1.0;
        }
        let d = inverse_depths.len() as f64 / inverse_depths.iter().sum::<f64>();
        breathing_factor(self.breathing_m, d)
    }

    fn main_shots(&self) -> Vec<Shot> {
        self.orientations
            .iter()
            .enumerate()
            .map(|(k, &orientation)| Shot {
                name: self.options.frame_name(k),
                time_s: self.main_time(k),
                noise_id: k as u64,
                image_id: k as u32 + 1,
                orientation,
            })
            .collect()
    }

    fn neighbour_shots(&self) -> Vec<(usize, f64, Shot)> {
        let dt = 1.0 / self.config.frame_rate;
        self.main_shots()
            .into_iter()
            .enumerate()
            .flat_map(|(k, main)| {
                let (stem, ext) = main.name.rsplit_once('.').unwrap_or((&main.name, "png"));
                [(-1.0, "-1", 0u64), (1.0, "+1", 1u64)].map(|(sign, suffix, j)| {
                    (
                        k,
                        sign * dt,
                        Shot {
                            name: format!("neighbours/{stem}{suffix}.{ext}"),
                            time_s: main.time_s + sign * dt,
                            noise_id: NEIGHBOUR_FRAME_IDS + 2 * k as u64 + j,
                            image_id: main.image_id,
                            orientation: main.orientation,
                        },
                    )
                })
            })
            .collect()
    }

    fn full_rate_times(&self) -> Vec<f64> {
        if self.config.full_rate_width.is_none() {
            return Vec::new();
        }
        let last = self.main_time(self.orientations.len().saturating_sub(1));
        let count = (last * self.config.frame_rate + 1e-9).floor() as usize + 1;
        (0..count)
            .map(|j| j as f64 / self.config.frame_rate)
            .collect()
    }

    /// The truth of the shots (no rendering), in order.
    fn shot_truth(&self, shots: &[Shot]) -> Vec<TruthFrame> {
        shots
            .par_iter()
            .map(|shot| {
                let camera = breathing_camera(&self.camera, self.breathing(shot.time_s));
                frame_truth_moving(
                    self.scene,
                    &camera,
                    &self.trajectory,
                    &self.shutter(shot.time_s),
                    (shot.image_id, &shot.name, shot.orientation),
                    self.options.margin_px,
                )
            })
            .collect()
    }

    /// Renders `shots` with the preset camera `camera` (of any size) into `dir`; PNG unless
    /// `render.jpeg_quality` is set.
    fn render(
        &self,
        camera: &BrownCamera,
        shots: &[Shot],
        dir: &Path,
        render: &RenderConfig,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<(), SimError> {
        let renderer = ShotRenderer::new(self, camera, shots, render);
        shots.par_iter().enumerate().try_for_each(|(i, shot)| {
            let frame = renderer.frame(i, shot)?;
            let path = dir.join(&shot.name);
            if let Some(parent) = path.parent() {
                std::fs::create_dir_all(parent).map_err(|e| WriteError::new(parent, e))?;
            }
            frame.write(&path)?;
            progress(self.done.fetch_add(1, Ordering::Relaxed) + 1);
            Ok(())
        })
    }

    /// Renders `shots` in their order and pipes them to ffmpeg as raw RGB into `mp4` (written
    /// beside it and renamed at the end): a few frames at a time in parallel, the previous
    /// group written by a second thread while the next renders.
    fn stream(
        &self,
        camera: &BrownCamera,
        shots: &[Shot],
        mp4: &Path,
        render: &RenderConfig,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<(), SimError> {
        use std::io::{Read, Write};
        let ffmpeg_error = |reason: String| SimError::Ffmpeg { reason };
        let partial = mp4.with_extension("partial.mp4");
        let mut child = std::process::Command::new("ffmpeg")
            .args([
                "-y",
                "-loglevel",
                "error",
                "-f",
                "rawvideo",
                "-pix_fmt",
                "rgb24",
            ])
            .arg("-s")
            .arg(format!("{}x{}", camera.width, camera.height))
            .arg("-framerate")
            .arg(format!("{}", self.config.frame_rate))
            .args(["-i", "-"])
            .args(X264)
            .arg(&partial)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .map_err(|e| {
                ffmpeg_error(format!(
                    "cannot run ffmpeg ({e}); streaming the video needs it ({FFMPEG_INSTALL})"
                ))
            })?;
        let (Some(mut stdin), Some(mut stderr)) = (child.stdin.take(), child.stderr.take()) else {
            let _ = child.kill();
            return Err(ffmpeg_error("ffmpeg's pipes could not be opened".into()));
        };
        let renderer = ShotRenderer::new(self, camera, shots, render);
        let group = 2 * rayon::current_num_threads();
        let result = std::thread::scope(|scope| {
            let errors = scope.spawn(move || {
                let mut text = String::new();
                let _ = stderr.read_to_string(&mut text);
                text
            });
            let (send, receive) = std::sync::mpsc::sync_channel::<Vec<Frame>>(1);
            let writer = scope.spawn(move || -> std::io::Result<()> {
                for frames in receive {
                    for frame in frames {
                        stdin.write_all(frame.image.as_raw())?;
                    }
                }
                stdin.flush()
            });
            let mut rendered = Ok(());
            for (g, chunk) in shots.chunks(group).enumerate() {
                let frames: Result<Vec<Frame>, SimError> = chunk
                    .par_iter()
                    .enumerate()
                    .map(|(i, shot)| renderer.frame(g * group + i, shot))
                    .collect();
                match frames {
                    Ok(frames) => {
                        let n = frames.len();
                        if send.send(frames).is_err() {
                            break; // the writer stopped: its error says why
                        }
                        progress(self.done.fetch_add(n, Ordering::Relaxed) + n);
                    }
                    Err(e) => {
                        rendered = Err(e);
                        break;
                    }
                }
            }
            drop(send);
            let written = writer.join();
            let status = child.wait();
            let text = errors.join().unwrap_or_default();
            rendered?;
            let failed = |what: String| ffmpeg_error(format!("{what}: {}", text.trim()));
            match written {
                Ok(Ok(())) => {}
                Ok(Err(e)) => return Err(failed(format!("writing to ffmpeg failed ({e})"))),
                Err(_) => return Err(failed("the thread writing to ffmpeg failed".into())),
            }
            match status {
                Ok(s) if s.success() => Ok(()),
                Ok(s) => Err(failed(format!("ffmpeg failed ({s})"))),
                Err(e) => Err(failed(format!("waiting for ffmpeg failed ({e})"))),
            }
        });
        if let Err(e) = result {
            let _ = std::fs::remove_file(&partial);
            return Err(e);
        }
        std::fs::rename(&partial, mp4).map_err(|e| WriteError::new(mp4, e))?;
        Ok(())
    }

    /// The extracted frames' truth without rendering (for [`super::simulate::lab_geometry`]),
    /// with their neighbours' when `neighbours` is on.
    #[must_use]
    pub fn truth_frames(&self) -> Vec<TruthFrame> {
        let mut frames = self.shot_truth(&self.main_shots());
        if self.config.neighbours {
            self.attach_neighbours(&mut frames);
        }
        frames
    }

    fn attach_neighbours(&self, frames: &mut [TruthFrame]) {
        let shots = self.neighbour_shots();
        let list: Vec<Shot> = shots.iter().map(|(_, _, s)| s.clone()).collect();
        let truth = self.shot_truth(&list);
        for ((k, dt, _), mut t) in shots.into_iter().zip(truth) {
            if let Some(m) = t.motion.as_mut() {
                m.dt_s = Some(dt);
            }
            frames[k].neighbours.push(t);
        }
    }

    /// Renders the extracted frames into `out/frames` and returns their truth.
    ///
    /// # Errors
    ///
    /// A frame that cannot be encoded or written.
    pub fn film_main(
        &self,
        out: &Path,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Vec<TruthFrame>, SimError> {
        let dir = out.join("frames");
        std::fs::create_dir_all(&dir).map_err(|e| WriteError::new(&dir, e))?;
        let shots = self.main_shots();
        self.render(&self.camera, &shots, &dir, &self.options.render, progress)?;
        Ok(self.shot_truth(&shots))
    }

    /// Renders the neighbours (when on) into `out/frames/neighbours`, adds their truth to
    /// `frames`, writes `out/frames/frames.json`, and renders the full-rate video (when on).
    /// Call it after the sparse model is made: COLMAP reads the frames folder recursively.
    ///
    /// # Errors
    ///
    /// A frame or file that cannot be written.
    pub fn film_rest(
        &self,
        frames: &mut [TruthFrame],
        out: &Path,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<VideoTruth, SimError> {
        let dir = out.join("frames");
        if self.config.neighbours {
            let shots: Vec<Shot> = self
                .neighbour_shots()
                .into_iter()
                .map(|(_, _, s)| s)
                .collect();
            self.render(&self.camera, &shots, &dir, &self.options.render, progress)?;
            self.attach_neighbours(frames);
        }
        let sidecar = FramesSidecar {
            schema: FRAMES_SCHEMA.into(),
            frames: frames
                .iter()
                .map(|f| FramesEntry {
                    name: f.name.clone(),
                    time_s: f.motion.as_ref().map_or(0.0, |m| m.time_s),
                    neighbours: f
                        .neighbours
                        .iter()
                        .map(|n| NeighbourEntry {
                            name: n.name.clone(),
                            dt_s: n.motion.as_ref().and_then(|m| m.dt_s).unwrap_or(0.0),
                        })
                        .collect(),
                })
                .collect(),
        };
        write_json(&dir.join("frames.json"), &sidecar)?;
        let full_rate = match self.config.full_rate_width {
            Some(width) => Some(self.film_full_rate(width, out, progress)?),
            None => None,
        };
        Ok(self.truth(full_rate))
    }

    /// How the extracted frames see surface points, for the SfM stand-in's features: the
    /// exact rolling-shutter pixel of a point seen ([`Filming::dense_observer`] at the point
    /// itself).
    pub fn sparse_observer(
        &self,
    ) -> impl Fn(usize, &Point3<f64>, &Vector3<f64>) -> Option<Vector2<f64>> + Sync + '_ {
        let dense = self.dense_observer();
        move |f, p, n| dense(f, p, n, p).map(|(uv, _)| uv)
    }

    /// How the extracted frames see surface points, for the site's dense observations: point
    /// `p` (normal `n`) in frame `f` when in front, facing the camera, inside the frame (1 px
    /// margin) and unoccluded at the time it is seen; then the exact rolling-shutter pixel of
    /// `at` (`p`, or where the reconstruction misplaces it) and the camera centre at that
    /// time ([`super::dense::Observer`]).
    pub fn dense_observer(&self) -> impl super::dense::ObserverFn + '_ {
        let cameras: Vec<BrownCamera> = (0..self.orientations.len())
            .map(|k| breathing_camera(&self.camera, self.breathing(self.main_time(k))))
            .collect();
        move |f, p, n, at| {
            let camera = &cameras[f];
            let shutter = self.shutter(self.main_time(f));
            let frame_pose = self.trajectory.cam_from_world(shutter.time_s);
            // Far outside the frame at the frame time: not worth the row search (the rolling
            // shutter moves points by pixels, not by a tenth of the frame).
            let uv = camera.project_world(&frame_pose, &p.coords)?;
            if !camera.contains(&uv, -0.1 * f64::from(camera.width)) {
                return None;
            }
            let seen = project_rolling_shutter(
                camera,
                &shutter,
                |t| self.trajectory.cam_from_world(t),
                &p.coords,
                Some(uv.y),
            )?;
            let eye =
                crate::geometry::pose::camera_centre(&self.trajectory.cam_from_world(seen.time_s));
            if n.dot(&(eye - p)) <= 0.0
                || !camera.contains(&seen.uv, 1.0)
                || !self.scene.visible(&eye, p, 1e-4)
            {
                return None;
            }
            if at == p {
                return Some((seen.uv, eye));
            }
            let moved = project_rolling_shutter(
                camera,
                &shutter,
                |t| self.trajectory.cam_from_world(t),
                &at.coords,
                Some(seen.uv.y),
            )?;
            Some((moved.uv, eye))
        }
    }

    /// The video's truth record.
    #[must_use]
    pub fn truth(&self, full_rate: Option<FullRateTruth>) -> VideoTruth {
        VideoTruth {
            config: self.config.clone(),
            readout_s: self.readout_s,
            exposure_s: self.config.exposure_s,
            frame_rate: self.config.frame_rate,
            focus_breathing_m: self.breathing_m,
            focus_reference_m: FOCUS_REFERENCE_M,
            trajectory: self.trajectory.clone(),
            full_rate,
        }
    }

    fn film_full_rate(
        &self,
        width: u32,
        out: &Path,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<FullRateTruth, SimError> {
        let dir = out.join("video");
        std::fs::create_dir_all(&dir).map_err(|e| WriteError::new(&dir, e))?;
        let height = (f64::from(width) * f64::from(self.camera.height)
            / f64::from(self.camera.width))
        .round() as u32;
        let camera = self.camera.scaled(width, height);
        let interval_frames = (self.config.interval_s * self.config.frame_rate).round() as usize;
        let shots: Vec<Shot> = self
            .full_rate_times()
            .into_iter()
            .enumerate()
            .map(|(j, time_s)| {
                let k = (j / interval_frames).min(self.orientations.len() - 1);
                Shot {
                    name: format!("frame_{:05}.png", j + 1),
                    time_s,
                    noise_id: VIDEO_FRAME_IDS + j as u64,
                    image_id: 0,
                    orientation: self.orientations[k],
                }
            })
            .collect();
        let render = RenderConfig {
            jpeg_quality: None,
            ..self.options.render.clone()
        };
        if self.config.stream_full_rate {
            self.stream(&camera, &shots, &out.join("video.mp4"), &render, progress)?;
        } else {
            self.render(&camera, &shots, &dir, &render, progress)?;
        }
        let motion = VideoMotion {
            schema: VIDEO_MOTION_SCHEMA.into(),
            frame_rate: self.config.frame_rate,
            width,
            height,
            readout_s: self.readout_s,
            exposure_s: self.config.exposure_s,
            frames: shots
                .iter()
                .enumerate()
                .map(|(j, shot)| {
                    let m = self.trajectory.motion(shot.time_s);
                    VideoFrameMotion {
                        name: shot.name.clone(),
                        time_s: shot.time_s,
                        angular_velocity: m.angular_velocity.into(),
                        linear_velocity: m.linear_velocity.into(),
                        angular_speed_deg_s: m.angular_velocity.norm().to_degrees(),
                        linear_speed_m_s: m.linear_velocity.norm(),
                        extracted: (j % interval_frames == 0)
                            .then(|| self.options.frame_name(j / interval_frames)),
                    }
                })
                .collect(),
        };
        write_json(&dir.join("motion.json"), &motion)?;
        let (mp4, note) = if self.config.stream_full_rate {
            (Some("video.mp4".into()), None)
        } else if self.config.encode {
            encode_mp4(&dir, self.config.frame_rate, &out.join("video.mp4"))
        } else {
            (None, Some("encoding not asked for".into()))
        };
        Ok(FullRateTruth {
            width,
            height,
            frames: shots.len(),
            streamed: self.config.stream_full_rate,
            mp4,
            note,
        })
    }
}

/// What rendering a list of shots shares: each shot's focus-breathing factor and the ray grid
/// of the widest of them.
struct ShotRenderer<'a, 'v> {
    video: &'a Filming<'v>,
    camera: &'a BrownCamera,
    render: &'a RenderConfig,
    factors: Vec<f64>,
    lowest: f64,
    rays: RayGrid,
}

impl<'a, 'v> ShotRenderer<'a, 'v> {
    fn new(
        video: &'a Filming<'v>,
        camera: &'a BrownCamera,
        shots: &[Shot],
        render: &'a RenderConfig,
    ) -> Self {
        let factors: Vec<f64> = shots
            .par_iter()
            .map(|s| video.breathing(s.time_s))
            .collect();
        let lowest = factors.iter().copied().fold(1.0, f64::min);
        let rays = RayGrid::new(&breathing_camera(camera, lowest));
        ShotRenderer {
            video,
            camera,
            render,
            factors,
            lowest,
            rays,
        }
    }

    /// Renders shot `i` of the list (`shot`) at its time with the moving rolling-shutter camera.
    fn frame(&self, i: usize, shot: &Shot) -> Result<Frame, SimError> {
        let factor = self.factors[i];
        let frame_camera = breathing_camera(self.camera, factor);
        let shutter = self.video.shutter(shot.time_s);
        let (t0, t1) = shutter.span();
        let poses = PoseTable::new(|t| self.video.trajectory.cam_from_world(t), t0, t1);
        let view = MovingView {
            camera: &frame_camera,
            rays: &self.rays,
            ray_scale: self.lowest / factor,
            poses: &poses,
            shutter,
        };
        render_frame_moving(
            self.video.scene,
            &view,
            self.video.gain,
            self.render,
            self.video.options.seed,
            shot.noise_id,
        )
        .map_err(|source| SimError::Encode {
            name: shot.name.clone(),
            source,
        })
    }
}

/// Runs ffmpeg (an external program, like COLMAP) on `dir/frame_%05d.png` ([`X264`]). Returns the file name, or why there is none.
fn encode_mp4(dir: &Path, frame_rate: f64, mp4: &Path) -> (Option<String>, Option<String>) {
    let pattern = dir.join("frame_%05d.png");
    let out = std::process::Command::new("ffmpeg")
        .args(["-y", "-loglevel", "error", "-framerate"])
        .arg(format!("{frame_rate}"))
        .arg("-i")
        .arg(&pattern)
        .args(X264)
        .arg(mp4)
        .output();
    match out {
        Ok(o) if o.status.success() => (Some("video.mp4".into()), None),
        Ok(o) => (
            None,
            Some(format!(
                "ffmpeg failed ({}): {}; the PNG frames are kept",
                o.status,
                String::from_utf8_lossy(&o.stderr).trim()
            )),
        ),
        Err(_) => (
            None,
            Some(format!(
                "ffmpeg is not on the PATH ({FFMPEG_INSTALL}); the PNG frames are kept"
            )),
        ),
    }
}

/// Removes the video outputs an earlier simulation may have left in `out` (only files of the
/// names this module writes: a re-run with other options must not leave stale neighbours for
/// COLMAP, which reads the frames folder recursively, or a stale sidecar for `calibrate`).
///
/// # Errors
///
/// A file that exists but cannot be removed.
pub fn clear_video_outputs(out: &Path) -> Result<(), WriteError> {
    let remove = |path: &Path| match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(WriteError::new(path, e)),
        _ => Ok(()),
    };
    let ours = |dir: &Path, keep: &dyn Fn(&str) -> bool| -> Result<(), WriteError> {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return Ok(());
        };
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if keep(&name) {
                remove(&entry.path())?;
            }
        }
        Ok(())
    };
    remove(&out.join("frames").join("frames.json"))?;
    ours(&out.join("frames").join("neighbours"), &|n| {
        n.starts_with("frame_")
            && [".png", ".jpg"]
                .iter()
                .any(|e| n.ends_with(&format!("-1{e}")) || n.ends_with(&format!("+1{e}")))
    })?;
    ours(&out.join("video"), &|n| {
        n == "motion.json" || (n.starts_with("frame_") && n.ends_with(".png"))
    })?;
    remove(&out.join("video.mp4"))
}

fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), WriteError> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| WriteError::new(path, std::io::Error::other(e)))?;
    write_bytes_atomic(path, text.as_bytes())
}

/// A [`FrameMotion`]'s speeds: |ω| (°/s) and |ν| (m/s).
#[must_use]
pub fn speeds(motion: &FrameMotion) -> (f64, f64) {
    (
        Vector3::from(motion.angular_velocity).norm().to_degrees(),
        Vector3::from(motion.linear_velocity).norm(),
    )
}
