#!/usr/bin/env python3
"""How far a simulated video's neighbouring frames at +-1/fps are from constant-velocity motion:
per extracted frame, the angular velocity implied by its two true neighbours (the central
difference of their true rotations, what the calibration's constant-velocity motion fits to
the neighbours) against the true angular velocity at the frame time (what the frame's own rows
see over the readout time).

Reads only the simulator's truth (`truth.json` of `pipemeasure simulate lab --video
--neighbours`): frames' qvec, their neighbours' qvec and dt_s, and `motion.angular_velocity`
(camera frame, [w]x = dR/dt R^T). Prints the mean, median and standard deviation of the
relative speed error (w_nb - w).w/|w|^2 over the frames, and the mean velocity error vector
(deg/s, camera axes) with its standard deviation: a mean beyond sd/sqrt(frames) is common to
all frames, which a readout time and the intrinsics can absorb.

    /usr/bin/python3 scripts/neighbour_velocity.py LAB/truth.json
"""
import json
import sys

import numpy as np


def rotation(q):
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def log(r):
    angle = np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2
    return v * (angle / np.sin(angle) if angle > 1e-12 else 1.0)


def main(path):
    truth = json.load(open(path))
    rel, diffs, speeds = [], [], []
    for f in truth["frames"]:
        motion, neighbours = f.get("motion"), f.get("neighbours", [])
        if not motion or len(neighbours) != 2:
            continue
        w = np.array(motion["angular_velocity"])
        r0 = rotation(f["qvec"])
        (dm, rm), (dp, rp) = sorted(
            (n["motion"]["dt_s"], rotation(n["qvec"])) for n in neighbours
        )
        w_nb = (log(rp @ r0.T) - log(rm @ r0.T)) / (dp - dm)
        rel.append(np.dot(w_nb - w, w) / np.dot(w, w))
        diffs.append(w_nb - w)
        speeds.append(np.linalg.norm(w))
    if not rel:
        sys.exit(f"{path}: no frame with two neighbours and a motion")
    rel, diffs = np.array(rel), np.degrees(np.array(diffs))
    print(f"{len(rel)} frames, mean speed {np.degrees(np.mean(speeds)):.2f} deg/s")
    print(
        f"relative speed error of the neighbours' central difference: mean {rel.mean():+.4f}, "
        f"median {np.median(rel):+.4f}, sd {rel.std():.4f}"
    )
    sd = diffs.std(0)
    print(
        "velocity error (deg/s, camera x y z): mean "
        + " ".join(f"{m:+.3f}" for m in diffs.mean(0))
        + ", sd "
        + " ".join(f"{s:.3f}" for s in sd)
        + ", mean / (sd/sqrt(n)) "
        + " ".join(f"{m / (s / np.sqrt(len(rel))):+.1f}" for m, s in zip(diffs.mean(0), sd))
    )


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: neighbour_velocity.py LAB/truth.json")
    main(sys.argv[1])
