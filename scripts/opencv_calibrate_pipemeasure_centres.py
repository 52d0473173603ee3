#!/usr/bin/env python3
"""A known-target calibration of BoofCV's two hand-held videos from pipemeasure's own dot
centres: OpenCV's `calibrateCamera` with the grids' printed layout, fed the centres of
`pipemeasure detect` (dark discs, semi-minor axis >= 2 px; no eccentricity correction). It
separates what the centres give from what pipemeasure's free-network self-calibration (which
knows nothing of the grid's flatness or layout) makes of them.

* 8x10 video (every 15th frame): each of the 80 grid positions OpenCV found
  (tests/fixtures/boofcv_video_grid.json, 39 of the 42 frames) takes the one pipemeasure
  detection within 0.3 of its spacing; the layout is 2.5 units apart.
* hexagonal video (every 15th frame, 35 frames): the hexagonal lattice grown over the detections
  (scripts/boofcv_detection_eval.py) indexes each dot; frames whose lattice is not the whole
  24x28 grid are left out. BoofCV's layout is equilateral: neighbours 1.2 units apart, at 60°.
  Each frame has its own lattice origin and orientation; calibrateCamera gives each its pose.
* the stills the same way: the 8x10 stills against OpenCV's own grid (another zoom setting of
  the camera: f ≈ 456 px), the hexagonal stills with their lattice (those with the whole grid).

Per set, BoofCV's two published cameras are also held fixed (only the poses adjusted) to show
how well they fit these dots.

Prints, per video and model (k1, k2 = BoofCV's model; k1, k2, p1, p2), OpenCV's RMS and the
intrinsics in pipemeasure's pixel convention (OpenCV + 0.5) with OpenCV's σ.

Run from the repository root (Debian: ffmpeg, python3-opencv, OpenCV 4.6):

    /usr/bin/python3 scripts/opencv_calibrate_pipemeasure_centres.py target/release/pipemeasure
"""

import json
import pathlib
import subprocess
import sys
import tempfile

import cv2
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from boofcv_detection_eval import (  # noqa: E402
    DATA, FIXTURE, detect, hex_lattice, opencv_grid, score_hex, spacing)


def extract(video, tmp):
    subprocess.run(["ffmpeg", "-loglevel", "error", "-i", str(DATA / video / "movie.mp4"),
                    "-vf", "select=not(mod(n\\,15))", "-vsync", "vfr", "-q:v", "2",
                    f"{tmp}/frame_%04d.jpg"], check=True)
    return sorted(pathlib.Path(tmp).glob("frame_*.jpg"))


def grid_view(grid, rows, cols, dark):
    """The 8x10 layout (2.5 apart) and, at each of OpenCV's grid positions, the one dark
    detection within 0.3 of its spacing; None unless every position has exactly one."""
    ours = []
    for p, s in zip(grid, spacing(grid, rows, cols)):
        near = np.flatnonzero(np.linalg.norm(dark - p, axis=1) < 0.3 * s)
        if len(near) != 1:
            return None
        ours.append(dark[near[0]])
    layout = np.zeros((rows * cols, 3), np.float32)
    layout[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * 2.5
    return layout, np.array(ours, np.float32).reshape(-1, 1, 2) - 0.5


def collect(views):
    """(objects, images) of the views that are not None."""
    kept = [v for v in views if v is not None]
    return [v[0] for v in kept], [v[1] for v in kept]


def regular_views(binary):
    fixture = json.loads(FIXTURE.read_text())
    with tempfile.TemporaryDirectory() as tmp:
        extract("video_regular", tmp)
        frames = fixture["frames"]
        det = detect(binary, ["--min-semi-minor", "2", "--polarity", "dark"],
                     [pathlib.Path(tmp) / f["frame"] for f in frames])
    return collect(grid_view(np.array(f["centres"]), f["rows"], f["cols"], det[f["frame"]][0])
                   for f in frames)


def regular_still_views(binary):
    paths = sorted((DATA / "stills_regular").glob("*.jpg"))
    det = detect(binary, ["--min-semi-minor", "3", "--polarity", "dark"], paths)
    refs = [(path, opencv_grid(path)) for path in paths]
    return collect(grid_view(*ref, det[path.name][0]) for path, ref in refs if ref is not None)


def hexagonal_views(binary, paths=None):
    if paths is None:
        with tempfile.TemporaryDirectory() as tmp:
            paths = extract("video_hexagonal", tmp)
            det = detect(binary, ["--min-semi-minor", "2", "--polarity", "dark"], paths)
    else:
        det = detect(binary, ["--min-semi-minor", "3", "--polarity", "dark"], paths)
    objects, images = [], []
    for path in paths:
        dark = det[path.name][0]
        nodes, full, _, off_dark, _, conflicts = score_hex(dark, np.zeros((0, 2)))
        if not full or off_dark or conflicts:
            continue
        index, _ = hex_lattice(dark)
        keys = sorted(index)
        ij = np.array([index[k] for k in keys], float)
        layout = np.zeros((len(keys), 3), np.float32)
        layout[:, 0] = 1.2 * (ij[:, 0] + 0.5 * ij[:, 1])
        layout[:, 1] = 1.2 * np.sqrt(3) / 2 * ij[:, 1]
        objects.append(layout)
        images.append(np.array(dark[keys], np.float32).reshape(-1, 1, 2) - 0.5)
    return objects, images


# BoofCV's two published calibrations of the camera (BoofCV's pixels: OpenCV's convention).
BOOFCV = {
    "BoofCV's dot-video calibration": (702.5492, 703.6580, 314.6070, 247.5081, -0.27349, 0.14570),
    "BoofCV's chessboard calibration": (701.0, 698.65, 308.46, 246.84, -0.2556, 0.1000),
}


def fixed_rms(objects, images, camera):
    """The reprojection RMS with the camera held at `camera` (fx, fy, cx, cy, k1, k2) and only
    each frame's pose adjusted."""
    fx, fy, cx, cy, k1, k2 = camera
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    dist = np.array([k1, k2, 0, 0, 0])
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_FOCAL_LENGTH
             | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2
             | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST)
    return cv2.calibrateCamera(objects, images, (640, 480), k, dist, flags=flags)[0]


def calibrate(name, objects, images):
    print(f"{name}: {len(images)} frames, {sum(len(i) for i in images)} dots")
    for ref, camera in BOOFCV.items():
        print(f"  poses only, camera held at {ref}: RMS {fixed_rms(objects, images, camera):.3f} px")
    for model, flags in [
        ("k1, k2", cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST),
        ("k1, k2, p1, p2", cv2.CALIB_FIX_K3),
    ]:
        out = cv2.calibrateCameraExtended(objects, images, (640, 480), None, None, flags=flags)
        rms, k, dist, std = out[0], out[1], out[2].ravel(), out[5].ravel()
        print(
            f"  {model}: RMS {rms:.3f} px; fx {k[0, 0]:.1f} ± {std[0]:.1f}, "
            f"fy {k[1, 1]:.1f} ± {std[1]:.1f}, u0 {k[0, 2] + 0.5:.2f} ± {std[2]:.2f}, "
            f"v0 {k[1, 2] + 0.5:.2f} ± {std[3]:.2f}, k1 {dist[0]:.4f}, k2 {dist[1]:.4f}, "
            f"p1 {dist[2]:.5f}, p2 {dist[3]:.5f}"
        )


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    binary = sys.argv[1]
    print(f"OpenCV {cv2.__version__}")
    calibrate("8x10 video, pipemeasure's centres", *regular_views(binary))
    calibrate("hexagonal video, pipemeasure's centres", *hexagonal_views(binary))
    calibrate("8x10 stills, pipemeasure's centres", *regular_still_views(binary))
    hex_stills = sorted((DATA / "stills_hexagonal").glob("*.jpg"))
    calibrate("hexagonal stills, pipemeasure's centres", *hexagonal_views(binary, hex_stills))


if __name__ == "__main__":
    main()
