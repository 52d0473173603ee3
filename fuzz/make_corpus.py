#!/usr/bin/env python3
"""Builds the committed seed corpus of the fuzz targets (fuzz/corpus/TARGET/).

Seeds are small: valid files of every format (cut from ../shared/data where the real files are
small enough or can be trimmed consistently, otherwise written here), the hostile cases of
issue 21, and a few near-misses. Run from the repository root:

    python3 fuzz/make_corpus.py            # needs ffmpeg for the frames

Deterministic: the same files every run.
"""
import json
import os
import shutil
import struct
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")
CORPUS = os.path.join(ROOT, "fuzz", "corpus")
SEP = b"\xffPM-FILE\xff"


def put(target, name, data):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


# ---------------------------------------------------------------- PLY
def ply_header(fmt, elements, comments=()):
    h = "ply\nformat %s 1.0\n" % fmt
    for c in comments:
        h += "comment %s\n" % c
    for name, count, props in elements:
        h += "element %s %d\n" % (name, count)
        for p in props:
            h += "property %s\n" % p
    return (h + "end_header\n").encode()


XYZ = ["float x", "float y", "float z"]


def ply_corpus():
    a = "ascii"
    put("ply_ascii", "xyz.ply", ply_header(a, [("vertex", 3, XYZ)]) + b"0 0 0\n1 2 3\n-1.5 .5 1E3\n")
    put("ply_ascii", "full.ply", ply_header(a, [
        ("vertex", 3, XYZ + ["float nx", "float ny", "float nz", "uchar red", "uchar green", "uchar blue", "float intensity"]),
        ("face", 1, ["list uchar int vertex_indices"])], ["made for the fuzzer"])
        + b"1 2 3 0 0 1 10 20 30 0.5\nnan inf 0 0 0 1 1 1 1 1\n-1.5 2.25 1e3 1 0 0 255 0 7 0\n3 0 1 2\n")
    put("ply_ascii", "types.ply", ply_header(a, [("vertex", 2, ["char x", "ushort y", "int z", "double w", "ushort red", "float green", "uint8 blue"])])
        + b"-5 65535 -70000 1e300 65535 0.5 9\n127 0 2147483647 -0 0 1 0\n")
    put("ply_ascii", "crlf.ply", ply_header(a, [("vertex", 1, XYZ)]).replace(b"\n", b"\r\n") + b"1 2 3\r\n")
    # Issue 21's hostile headers and bodies.
    put("ply_ascii", "huge_count.ply", b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\nproperty float x\nend_header\n")
    put("ply_ascii", "huge_version.ply", b"ply\nformat ascii 99999999999999999999.0\nend_header\n")
    put("ply_ascii", "dup_property.ply", ply_header(a, [("vertex", 1, XYZ + ["float x"])]) + b"1 2 3 4\n")
    put("ply_ascii", "dup_element.ply", ply_header(a, [("vertex", 1, XYZ), ("vertex", 1, XYZ)]) + b"1 2 3\n4 5 6\n")
    put("ply_ascii", "extra_tokens.ply", ply_header(a, [("vertex", 2, XYZ)]) + b"1 2 3\n4 5 6 7\n")
    put("ply_ascii", "trailing.ply", ply_header(a, [("vertex", 1, XYZ)]) + b"1 2 3\n4 5 6\n")
    put("ply_ascii", "comment_bytes.ply", b"ply\nformat ascii 1.0\ncomment \xe9\xff\xfe\nobj_info \x00\x01\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n")

    b = "binary_little_endian"
    body = b"".join(struct.pack("<fff", k, -k, 0.5) for k in range(4))
    put("ply_binary", "le.ply", ply_header(b, [("vertex", 4, XYZ)]) + body)
    body = b"".join(struct.pack(">dddf", k, -k, 0.5, 2.0 * k) for k in range(3))
    put("ply_binary", "be_double.ply", ply_header("binary_big_endian", [("vertex", 3, ["double x", "double y", "double z", "float intensity"])]) + body)
    rec = struct.pack("<hB", -300, 2) + struct.pack("<HH", 7, 8) + struct.pack("<bIHfB", -5, 70000, 0x8000, 0.5, 9)
    face = struct.pack("<I", 3) + struct.pack("<iii", 0, 1, 1)
    put("ply_binary", "lists.ply", ply_header(b, [
        ("vertex", 1, ["short x", "list uchar ushort l", "char y", "uint z", "ushort red", "float green", "uchar blue"]),
        ("face", 1, ["list uint int vertex_indices"])]) + rec + face)
    put("ply_binary", "junk_before.ply", ply_header(b, [("junk", 1000000000000, []), ("vertex", 1, XYZ)]) + bytes(12))
    put("ply_binary", "junk_after.ply", ply_header(b, [("vertex", 1, XYZ), ("junk", 1000000000000, [])]) + bytes(12))
    put("ply_binary", "dup_property.ply", ply_header(b, [("vertex", 1, XYZ + ["float x"])]) + bytes(16))
    put("ply_binary", "trailing.ply", ply_header(b, [("vertex", 1, XYZ)]) + bytes(12) + b"after")
    put("ply_binary", "negative_list.ply", ply_header(b, [("vertex", 1, XYZ + ["list char float l"])]) + bytes(12) + b"\xff")
    put("ply_binary", "lying_count.ply", ply_header(b, [("vertex", 4000000000, XYZ)]) + bytes(24))
    # The real mug scan (PCL), its first 64 vertices and its camera element.
    mug = open(os.path.join(DATA, "pcl_mug", "table_scene_mug_stereo_textured.ply"), "rb").read()
    end = mug.index(b"end_header\n") + len(b"end_header\n")
    header = mug[:end].replace(b"element vertex 307200", b"element vertex 64")
    camera_bytes = 4 * 15  # element camera 1: 15 float properties (see its header)
    n_cam_props = header.count(b"property float") - 3
    body = mug[end:end + 64 * 16] + mug[len(mug) - 4 * n_cam_props:]
    put("ply_binary", "mug_64.ply", header + body)


# ---------------------------------------------------------------- COLMAP
def colmap_models():
    """(cameras, images, points) of small consistent models, as tuples."""
    models = []
    cams = [(1, "SIMPLE_RADIAL", 480, 270, [380.0, 240.0, 135.0, 0.01]),
            (2, "OPENCV", 640, 480, [500.0, 501.0, 320.0, 240.0, 0.1, -0.02, 0.001, 0.002])]
    images = [(1, [1, 0, 0, 0], [0, 0, 0], 1, "frame_0001.png", [(10.5, 20.25, 1), (30.0, 40.0, -1), (50.0, 60.0, 2)]),
              (2, [0.9, 0.1, 0.3, -0.3], [0.5, -1, 2], 1, "frame_0002.png", [(11.5, 21.5, 1), (51.0, 61.0, 2)]),
              (5, [0.5, 0.5, -0.5, 0.5], [1.5, -2.25, 1e-7], 2, "sub/x y.jpg", [])]
    points = [(1, [1.0, 2.0, 3.0], [10, 20, 30], 0.5, [(1, 0), (2, 0)]),
              (2, [-1e3, 0.25, 7.0], [255, 0, 1], 1.25, [(1, 2), (2, 1)])]
    models.append((cams, images, points))
    models.append(([(3, "PINHOLE", 960, 540, [700.0, 700.0, 480.0, 270.0])],
                   [(7, [1, 0, 0, 0], [0, 0, 1], 3, "a.png", [])], []))
    return models


NUM_PARAMS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8,
              "OPENCV_FISHEYE": 8, "FULL_OPENCV": 12, "FOV": 5, "SIMPLE_RADIAL_FISHEYE": 4,
              "RADIAL_FISHEYE": 5, "THIN_PRISM_FISHEYE": 12}
MODEL_ID = {n: k for k, n in enumerate(NUM_PARAMS)}


def colmap_text(cams, images, points):
    c = "# Camera list\n" + "".join("%d %s %d %d %s\n" % (i, m, w, h, " ".join(repr(p) for p in ps)) for i, m, w, h, ps in cams)
    im = "# Image list\n"
    for i, q, t, cam, name, pts in images:
        im += "%d %s %s %d %s\n" % (i, " ".join(map(repr, q)), " ".join(map(repr, t)), cam, name)
        im += " ".join("%r %r %d" % p for p in pts) + "\n"
    p = "# 3D point list\n" + "".join(
        "%d %s %s %r %s\n" % (i, " ".join(map(repr, xyz)), " ".join(map(str, rgb)), e, " ".join("%d %d" % t for t in tr))
        for i, xyz, rgb, e, tr in points)
    return [c.encode(), im.encode(), p.encode()]


def colmap_binary(cams, images, points):
    c = struct.pack("<Q", len(cams))
    for i, m, w, h, ps in cams:
        c += struct.pack("<IiQQ", i, MODEL_ID[m], w, h) + b"".join(struct.pack("<d", p) for p in ps)
    im = struct.pack("<Q", len(images))
    for i, q, t, cam, name, pts in images:
        im += struct.pack("<I", i) + struct.pack("<7d", *q, *t) + struct.pack("<I", cam) + name.encode() + b"\0"
        im += struct.pack("<Q", len(pts))
        for x, y, pid in pts:
            im += struct.pack("<ddQ", x, y, pid if pid >= 0 else 2**64 - 1)
    p = struct.pack("<Q", len(points))
    for i, xyz, rgb, e, tr in points:
        p += struct.pack("<Q3d3Bd", i, *xyz, *rgb, e) + struct.pack("<Q", len(tr))
        p += b"".join(struct.pack("<II", *t) for t in tr)
    return [c, im, p]


def colmap_corpus():
    for k, (cams, images, points) in enumerate(colmap_models()):
        put("colmap_text", "model%d" % k, SEP.join(colmap_text(cams, images, points)))
        put("colmap_binary", "model%d" % k, SEP.join(colmap_binary(cams, images, points)))
    cams, images, points = colmap_models()[0]
    # Issue 21: a POINT3D_ID nobody defines, a missing last POINTS2D line, cameras 0 or 4.8e12 px wide.
    t = colmap_text(cams, images, points)
    put("colmap_text", "missing_point3d", SEP.join([t[0], t[1].replace(b"50.0 60.0 2", b"50.0 60.0 99"), t[2]]))
    put("colmap_text", "no_last_points2d", SEP.join([t[0], t[1].rstrip(b"\n").rsplit(b"\n", 1)[0] + b"\n", t[2]]))
    wide = [(1, "SIMPLE_RADIAL", 4800000000000, 270, [380.0, 240.0, 135.0, 0.01])] + cams[1:]
    put("colmap_text", "wide_camera", SEP.join(colmap_text(wide, images, points)))
    put("colmap_binary", "wide_camera", SEP.join(colmap_binary(wide, images, points)))
    zero = [(1, "SIMPLE_RADIAL", 0, 270, [0.0, 240.0, 135.0, 0.01])] + cams[1:]
    put("colmap_text", "zero_camera", SEP.join(colmap_text(zero, images, points)))
    b = colmap_binary(cams, images, points)
    put("colmap_binary", "lying_count", SEP.join([b[0], struct.pack("<Q", 2**64 - 1) + b[1][8:], b[2]]))


# ---------------------------------------------------------------- profile, TLS, BAL
def small_corpora():
    cal = os.path.join(ROOT, "calibrations")
    for name in sorted(os.listdir(cal)):
        if name.endswith(".json"):
            put("profile", name, open(os.path.join(cal, name), "rb").read())
    p30 = open(os.path.join(cal, "p30.json"), "rb").read()
    put("profile", "two_objects.json", p30 + b"\n" + p30)
    j = json.loads(p30)
    j["intrinsics"]["b1"] = -j["intrinsics"]["c"]
    put("profile", "fx_zero.json", json.dumps(j, indent=2))
    j = json.loads(p30)
    j["intrinsics"]["k1"] = -5.0
    put("profile", "folding.json", json.dumps(j, indent=2))
    j = json.loads(p30)
    j["rolling_shutter"] = {"readout_s": 0.02, "readout_std_s": 0.0001, "estimated": True}
    put("profile", "rolling_shutter.json", json.dumps(j, indent=2))
    put("profile", "minimal.json", b'{"schema":"pipemeasure.profile/1","device":"d","image":{"width":64,"height":48},"model":"brown","terms":[],"intrinsics":{"c":50,"u0":32,"v0":24,"k1":0,"k2":0,"k3":0,"p1":0,"p2":0,"b1":0,"b2":0}}')

    sidecar = {"schema": "pipemeasure.frames/1", "frames": [
        {"name": "frame_%04d.png" % k, "time_s": float(k),
         "neighbours": [{"name": "neighbours/frame_%04d-1.png" % k, "dt_s": -0.04},
                        {"name": "neighbours/frame_%04d+1.png" % k, "dt_s": 0.04}]}
        for k in range(1, 4)]}
    put("frames_sidecar", "three.json", json.dumps(sidecar, indent=2))
    put("frames_sidecar", "still.json", b'{"schema":"pipemeasure.frames/1","frames":[{"name":"a.png","time_s":0,"neighbours":[]}]}')
    bad = json.loads(json.dumps(sidecar))
    bad["frames"][0]["neighbours"][1]["name"] = bad["frames"][0]["neighbours"][0]["name"]
    bad["frames"][1]["name"] = "../escaped.png"
    put("frames_sidecar", "hostile.json", json.dumps(bad))

    put("tls_targets", "site.csv", "id,x,y,z\n1,500000.1,5600000.2,100.3\n2,500001.5,5600000.0,101.25\nT3,499999.0,5600002.0,99.0\n# a comment\n\n4,500000.5,5600001.5,100.0\n")
    put("tls_targets", "bad.csv", "id,x,y,z\n1,0,0,0\n1,nan,0,0\n2,1,2\n")

    lines = open(os.path.join(DATA, "bal", "problem-49-7776-pre.txt")).read().split("\n")
    nc, npt, nobs = map(int, lines[0].split())
    obs = [l.split() for l in lines[1:1 + nobs]]
    params = lines[1 + nobs:]
    keep_cams, keep_pts = 2, 12
    kept = [o for o in obs if int(o[0]) < keep_cams and int(o[1]) < keep_pts]
    out = ["%d %d %d" % (keep_cams, keep_pts, len(kept))] + [" ".join(o) for o in kept]
    out += params[:9 * keep_cams] + params[9 * nc:9 * nc + 3 * keep_pts]
    put("bal", "problem-2-12.txt", "\n".join(out) + "\n")
    put("bal", "tiny.txt", "2 1 2\n0 0 1.5 -2.0\n1 0 3e-1 4\n0.1\n0.2\n0.3\n1\n2\n3\n500\n0.01\n-0.002\n0\n0\n0\n0\n0\n5\n400\n0\n0\n1.0\n2.0\n-3.0\n")
    put("bal", "lying.txt", "1000000000 1000000000 1000000000\n0 0 1 1\n")


# ---------------------------------------------------------------- observations, vis
def binary_corpora():
    frames = [b"frame_0001.png", b"frame_0002.png"]
    labels = [b"wall", b"pipe-4in"]
    o = b"PMOBS001" + struct.pack("<I", len(frames)) + b"".join(struct.pack("<H", len(f)) + f for f in frames)
    o += struct.pack("<H", len(labels)) + b"".join(struct.pack("<H", len(l)) + l for l in labels)
    pts = [(7, 1, (1.0, 2.0, 3.0), [(0, 10.5, 20.5), (1, 11.0, 21.0)]), (9, 0, (-1.0, 0.0, 5e5), [(1, 0.0, 0.0)])]
    o += struct.pack("<Q", len(pts))
    for i, lab, xyz, obs in pts:
        o += struct.pack("<QB3dB", i, lab, *xyz, len(obs)) + b"".join(struct.pack("<Iff", *x) for x in obs)
    put("observations", "two_points.bin", o)
    put("observations", "lying_count.bin", o[:o.index(struct.pack("<Q", 2))] + struct.pack("<Q", 2**63) + b"\0" * 40)

    vis = struct.pack("<Q", 3) + struct.pack("<I3I", 3, 0, 3, 7) + struct.pack("<I", 0) + struct.pack("<II", 1, 2)
    put("vis", "three_points.vis", struct.pack("<I", 3) + vis)
    put("vis", "lying.vis", struct.pack("<I", 3) + struct.pack("<Q", 10**12) + vis[8:])


# ---------------------------------------------------------------- E57
def e57_corpus():
    d = os.path.join(DATA, "e57_testdata")
    for name in sorted(os.listdir(d)):
        path = os.path.join(d, name)
        # The bunnies (225-743 KB) would slow every run; the small files cover the format.
        if name.endswith(".e57") and os.path.getsize(path) <= 64 * 1024:
            shutil.copyfile(path, os.path.join(CORPUS, "e57", name))


# ---------------------------------------------------------------- frames
def frame_corpus():
    d = os.path.join(CORPUS, "frame")
    tmp = os.path.join(d, ".tmp")
    os.makedirs(tmp, exist_ok=True)
    variants = [
        ("rgb.png", ["-pix_fmt", "rgb24"]), ("grey16.png", ["-pix_fmt", "gray16be"]),
        ("rgba.png", ["-pix_fmt", "rgba"]), ("palette.png", ["-pix_fmt", "pal8"]),
        ("base.jpg", ["-q:v", "3"]), ("grey.jpg", ["-pix_fmt", "gray", "-q:v", "5"]),
        ("frame.tif", ["-pix_fmt", "rgb24", "-compression_algo", "lzw"]),
        ("grey16.tif", ["-pix_fmt", "gray16le"]), ("frame.bmp", ["-pix_fmt", "bgr24"]),
    ]
    for name, opts in variants:
        out = os.path.join(tmp, name)
        subprocess.run(["ffmpeg", "-loglevel", "error", "-y", "-f", "lavfi", "-i",
                        "testsrc=size=64x48:rate=1", "-frames:v", "1", "-map_metadata", "-1",
                        "-bitexact", *opts, out], check=True)
        data = open(out, "rb").read()
        # The first byte picks the expected size (see fuzz_targets/frame.rs): 1 = 64x48.
        put("frame", name, b"\x01" + data)
        if name == "base.jpg":
            put("frame", "cut.jpg", b"\x01" + data[:len(data) // 3])
        if name == "rgb.png":
            # A header that claims 16000x16000 (issue 21), and the frame with no size asked.
            put("frame", "claims_16000.png", b"\x00" + data[:16] + struct.pack(">II", 16000, 16000) + data[24:])
            put("frame", "any_size.png", b"\x00" + data)
    shutil.rmtree(tmp)


def main():
    if os.path.isdir(CORPUS):
        shutil.rmtree(CORPUS)
    for t in ["ply_ascii", "ply_binary", "colmap_text", "colmap_binary", "profile", "tls_targets",
              "e57", "bal", "observations", "vis", "frame", "frames_sidecar"]:
        os.makedirs(os.path.join(CORPUS, t), exist_ok=True)
    ply_corpus()
    colmap_corpus()
    small_corpora()
    binary_corpora()
    e57_corpus()
    frame_corpus()
    total = sum(len(fs) for _, _, fs in os.walk(CORPUS))
    print("%d seed files in %s" % (total, CORPUS), file=sys.stderr)


if __name__ == "__main__":
    main()
