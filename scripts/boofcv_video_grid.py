#!/usr/bin/env python3
"""Writes tests/fixtures/boofcv_video_grid.json: OpenCV's dot-grid centres in BoofCV's hand-held
video of its 8x10 grid (../shared/data/boofcv_circle_grids/video_regular/movie.mp4), on the
frames the real-data test extracts (every 15th frame, ffmpeg, JPEG quality 2).

An independent reference for `tests/real_data.rs`: OpenCV's `findCirclesGrid` (its own blob
detector, thresholds at several levels and blob moments) with a symmetric 8x10 or 10x8 pattern,
first as is and, where that fails, with OpenCV's clustering grid finder (the frames with strong
perspective). A frame where neither finds the whole grid is listed in `not_found`.

Centres are in pipemeasure's pixel convention (the first pixel's centre at (0.5, 0.5): OpenCV's
coordinates + 0.5), rounded to 0.001 px, in OpenCV's grid order (`rows` x `cols`, row-major).

Run from the repository root with OpenCV's Python bindings (Debian: python3-opencv, OpenCV 4.6):

    /usr/bin/python3 scripts/boofcv_video_grid.py
"""

import json
import pathlib
import subprocess
import sys
import tempfile

import cv2

MOVIE = pathlib.Path("../shared/data/boofcv_circle_grids/video_regular/movie.mp4")
OUT = pathlib.Path("tests/fixtures/boofcv_video_grid.json")
STEP = 15


def find_grid(gray):
    """OpenCV's 80 centres, its pattern (cols, rows) and the finder used, or None."""
    for finder, flags in [
        ("symmetric", cv2.CALIB_CB_SYMMETRIC_GRID),
        ("symmetric+clustering", cv2.CALIB_CB_SYMMETRIC_GRID | cv2.CALIB_CB_CLUSTERING),
    ]:
        for pattern in [(8, 10), (10, 8)]:
            found, centres = cv2.findCirclesGrid(gray, pattern, flags=flags)
            if found:
                return centres.reshape(-1, 2), pattern, finder
    return None


def main():
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            ["ffmpeg", "-loglevel", "error", "-i", str(MOVIE), "-vf",
             f"select=not(mod(n\\,{STEP}))", "-vsync", "vfr", "-q:v", "2",
             f"{tmp}/frame_%04d.jpg"],
            check=True,
        )
        paths = sorted(pathlib.Path(tmp).glob("frame_*.jpg"))
        frames, not_found = [], []
        for k, path in enumerate(paths):
            gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            result = find_grid(gray)
            name = path.name
            if result is None:
                not_found.append(name)
                continue
            centres, (cols, rows), finder = result
            frames.append({
                "frame": name,
                "video_frame": k * STEP,
                "finder": finder,
                "cols": cols,
                "rows": rows,
                "centres": [[round(float(u) + 0.5, 3), round(float(v) + 0.5, 3)]
                            for u, v in centres],
            })
    doc = {
        "source": str(MOVIE),
        "extraction": f"ffmpeg -i movie.mp4 -vf select=not(mod(n\\,{STEP})) -vsync vfr -q:v 2 "
                      "frame_%04d.jpg",
        "generator": "scripts/boofcv_video_grid.py",
        "opencv": cv2.__version__,
        "pixel_convention": "first pixel's centre at (0.5, 0.5) (OpenCV + 0.5)",
        "frames_extracted": len(paths),
        "not_found": not_found,
        "frames": frames,
    }
    OUT.write_text(json.dumps(doc, separators=(",", ":")) + "\n")
    print(f"{len(frames)} of {len(paths)} frames with the whole grid; not found: {not_found}",
          file=sys.stderr)


if __name__ == "__main__":
    main()
