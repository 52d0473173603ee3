#!/usr/bin/env python3
"""A peer's calibration of BoofCV's hand-held dot-grid video: OpenCV's `calibrateCamera` on the
grid centres OpenCV found in the every-15th frames (tests/fixtures/boofcv_video_grid.json,
written by scripts/boofcv_video_grid.py: 39 of the 42 frames), with the 8x10 grid's metric
layout (2.5 units apart). Two models: k1, k2 (BoofCV's model), and k1, k2, p1, p2. Prints the
intrinsics in pipemeasure's pixel convention (the fixture's: OpenCV + 0.5) and OpenCV's σ.

Run from the repository root (Debian: python3-opencv, OpenCV 4.6):

    /usr/bin/python3 scripts/opencv_calibrate_boofcv_video.py
"""

import json
import pathlib

import cv2
import numpy as np

FIXTURE = pathlib.Path(__file__).resolve().parent.parent / "tests/fixtures/boofcv_video_grid.json"
SPACING = 2.5


def main():
    data = json.loads(FIXTURE.read_text())
    objects, images = [], []
    for frame in data["frames"]:
        rows, cols = frame["rows"], frame["cols"]
        grid = np.zeros((rows * cols, 3), np.float32)
        grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * SPACING
        # Back to OpenCV's convention (the first pixel's centre at 0, 0).
        centres = np.array(frame["centres"], np.float32).reshape(-1, 1, 2) - 0.5
        objects.append(grid)
        images.append(centres)
    print(f"{len(images)} frames with the whole grid (OpenCV {cv2.__version__})")
    for name, flags in [
        ("k1, k2", cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST),
        ("k1, k2, p1, p2", cv2.CALIB_FIX_K3),
    ]:
        out = cv2.calibrateCameraExtended(objects, images, (640, 480), None, None, flags=flags)
        rms, k, dist, std = out[0], out[1], out[2].ravel(), out[5].ravel()
        print(
            f"{name}: RMS {rms:.3f} px; fx {k[0, 0]:.1f} ± {std[0]:.1f}, fy {k[1, 1]:.1f} ± {std[1]:.1f}, "
            f"u0 {k[0, 2] + 0.5:.2f} ± {std[2]:.2f}, v0 {k[1, 2] + 0.5:.2f} ± {std[3]:.2f} "
            f"(pipemeasure's pixels), k1 {dist[0]:.4f}, k2 {dist[1]:.4f}, p1 {dist[2]:.5f}, p2 {dist[3]:.5f}"
        )


if __name__ == "__main__":
    main()
