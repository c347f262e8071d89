#!/usr/bin/env python3
"""Writes the seed corpus of the bundle and ROS message fuzz targets (test/fuzz/corpus/{bundle,
ros_cloud,ros_keyframe,lsd_keyframe,lsd_graph}/) from the project's own generated worlds (the
build's BUILD/sim/demo and BUILD/sim/nodepth, pcr_pro_simulate with config/sim_demo.yaml; nothing
comes from ../shared/data): the bundle.yaml of agent_a (with depth) and of agent_b (without), and
from the world's two bags the first points of a map cloud, 16x12 crops of keyframes (with their
intrinsics moved to the crop) and the LSD-SLAM graph messages, plus the two regression inputs
that fuzzing once found (a denormal coordinate, an encoding with a newline) rebuilt on these
seeds. Each message seed is one message in ROS serialization, exactly the bytes a subscriber
deserializes. Deterministic for a given world.

Usage: /usr/bin/python3 test/fuzz/make_sim_seeds.py [BUILD_DIR]   (default build; Debian's
python3: it needs python3-rosbag, and BUILD_DIR/devel/setup.bash sourced for pcr_pro's messages)
"""
import copy
import io
import os
import shutil
import struct
import sys

import rosbag

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
BUILD = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build")
WORLD = os.path.join(BUILD, "sim", "demo")
NODEPTH = os.path.join(BUILD, "sim", "nodepth")
BAGS = WORLD
CORPUS = os.path.join(ROOT, "test", "fuzz", "corpus")
CROP_W, CROP_H = 16, 12
# The seeds this script owns (the rest of each directory, e.g. bundle/tiny_valid.yaml, is written by hand).
OWNED = {
    "bundle": ["agent_a_depth.yaml", "agent_b_nodepth.yaml"],
    "ros_cloud": ["agent_a_head_xyz32.msg", "agent_a_head_xyz64.msg", "organised_rgb_nan.msg",
                  "regression_denormal_extent.msg"],
    "ros_keyframe": ["agent_a_kf_mono8_16uc1.msg", "agent_b_kf_rgb8_32fc1.msg", "agent_a_kf_bgra8_nodepth.msg",
                     "regression_encoding_with_newline.msg"],
    "lsd_keyframe": [],
    "lsd_graph": [],
}


def read(bag_name):
    with rosbag.Bag(os.path.join(BAGS, bag_name)) as bag:
        return [(topic, msg) for topic, msg, _ in bag.read_messages()]


def write(target, name, msg):
    os.makedirs(os.path.join(CORPUS, target), exist_ok=True)
    buf = io.BytesIO()
    msg.serialize(buf)
    with open(os.path.join(CORPUS, target, name), "wb") as f:
        f.write(buf.getvalue())


def crop_rows(data, step, pixel_bytes, x0, y0, w, h):
    out = bytearray()
    for y in range(y0, y0 + h):
        start = y * step + x0 * pixel_bytes
        out += data[start:start + w * pixel_bytes]
    return bytes(out)


def crop_image(img, x0, y0, w, h, pixel_bytes):
    img.data = crop_rows(img.data, img.step, pixel_bytes, x0, y0, w, h)
    img.width, img.height, img.step = w, h, w * pixel_bytes


def crop_camera(info, x0, y0, w, h):
    k = list(info.K)
    k[2] -= x0
    k[5] -= y0
    info.K = k
    p = list(info.P)
    p[2] -= x0
    p[6] -= y0
    info.P = p
    info.width, info.height = w, h


def cloud_seeds(msgs):
    cloud = next(m for t, m in msgs if t == "/agent_a/cloud")
    n = 48
    head = copy.deepcopy(cloud)
    head.width, head.height = n, 1
    head.data = cloud.data[:n * cloud.point_step]
    head.row_step = n * cloud.point_step
    write("ros_cloud", "agent_a_head_xyz32.msg", head)

    # The same points as FLOAT64 fields.
    xyz = [struct.unpack_from("<3f", cloud.data, i * cloud.point_step) for i in range(n)]
    d64 = copy.deepcopy(head)
    for k, f in enumerate(d64.fields):
        f.offset, f.datatype = 8 * k, 8  # FLOAT64
    d64.point_step = 24
    d64.row_step = 24 * n
    d64.data = b"".join(struct.pack("<3d", *p) for p in xyz)
    write("ros_cloud", "agent_a_head_xyz64.msg", d64)

    # Organised 8 x 6 with an extra rgb field and a few NaN points (as a depth camera sends).
    org = copy.deepcopy(head)
    rgb = copy.deepcopy(org.fields[0])
    rgb.name, rgb.offset, rgb.datatype = "rgb", 12, 7  # FLOAT32
    org.fields.append(rgb)
    org.width, org.height, org.point_step = 8, 6, 16
    org.row_step = 8 * 16
    org.is_dense = False
    nan = float("nan")
    org.data = b"".join(struct.pack("<4f", *(p if i % 7 else (nan, nan, nan)), 0.5) for i, p in enumerate(xyz))
    write("ros_cloud", "organised_rgb_nan.msg", org)

    # Regression: a denormal coordinate (the cloud's extent once overflowed on it).
    den = copy.deepcopy(d64)
    den.data = struct.pack("<d", 5e-310) + d64.data[8:]
    write("ros_cloud", "regression_denormal_extent.msg", den)


def keyframe_seeds(msgs):
    kfs = [m for t, m in msgs if t.endswith("/keyframes")]
    # agent_a's first keyframe: mono8 + 16UC1 depth, centre crop.
    a = copy.deepcopy(kfs[0])
    x0, y0 = a.image.width // 2, a.image.height // 2
    crop_image(a.image, x0, y0, CROP_W, CROP_H, 1)
    crop_image(a.depth, x0, y0, CROP_W, CROP_H, 2)
    crop_camera(a.camera_info, x0, y0, CROP_W, CROP_H)
    write("ros_keyframe", "agent_a_kf_mono8_16uc1.msg", a)

    # agent_b keyframe: rgb8 (grey replicated) + 32FC1 depth [m], another crop.
    b = copy.deepcopy([m for t, m in msgs if t == "/agent_b/keyframes"][0])
    x0, y0 = 200, 150
    crop_image(b.image, x0, y0, CROP_W, CROP_H, 1)
    b.image.data = bytes(v for g in b.image.data for v in (g, g, g))
    b.image.encoding, b.image.step = "rgb8", 3 * CROP_W
    crop_image(b.depth, x0, y0, CROP_W, CROP_H, 2)
    mm = struct.unpack("<%dH" % (CROP_W * CROP_H), b.depth.data)
    b.depth.data = struct.pack("<%df" % len(mm), *(v / 1000.0 for v in mm))
    b.depth.encoding, b.depth.step = "32FC1", 4 * CROP_W
    crop_camera(b.camera_info, x0, y0, CROP_W, CROP_H)
    write("ros_keyframe", "agent_b_kf_rgb8_32fc1.msg", b)

    # No depth; bgra8 with padded rows.
    c = copy.deepcopy(a)
    c.image.data = b"".join(bytes(v for g in c.image.data[r * CROP_W:(r + 1) * CROP_W] for v in (g, g, g, 255)) +
                            b"\0\0\0\0" for r in range(CROP_H))
    c.image.encoding, c.image.step = "bgra8", 4 * CROP_W + 4
    c.depth = type(c.depth)()
    write("ros_keyframe", "agent_a_kf_bgra8_nodepth.msg", c)

    # Regression: an encoding with a newline inside ("rg\n8"), 2 bytes a pixel, no depth.
    r = copy.deepcopy(a)
    r.image.data = bytes(v for g in r.image.data for v in (g, g))
    r.image.encoding, r.image.step = "rg\n8", 2 * CROP_W
    r.depth = type(r.depth)()
    write("ros_keyframe", "regression_encoding_with_newline.msg", r)


def lsd_seeds(msgs):
    for t, m in msgs:
        if t.endswith("/lsd_slam/graph"):
            write("lsd_graph", t.split("/")[1] + "_graph.msg", m)
    for agent, x0, y0 in (("agent_a", 320, 240), ("agent_b", 300, 200)):
        m = copy.deepcopy(next(m for t, m in msgs if t == "/" + agent + "/lsd_slam/keyframes"))
        m.pointcloud = crop_rows(m.pointcloud, 12 * m.width, 12, x0, y0, CROP_W, CROP_H)
        m.width, m.height = CROP_W, CROP_H
        m.cx -= x0
        m.cy -= y0
        write("lsd_keyframe", agent + "_kf%d_crop.msg" % m.id, m)


def bundle_seeds():
    for src, name in ((os.path.join(WORLD, "agent_a"), "agent_a_depth.yaml"),
                      (os.path.join(NODEPTH, "agent_b"), "agent_b_nodepth.yaml")):
        shutil.copyfile(os.path.join(src, "bundle.yaml"), os.path.join(CORPUS, "bundle", name))


def main():
    for d in (WORLD, NODEPTH):
        if not os.path.isfile(os.path.join(d, "truth.yaml")):
            sys.exit("make_sim_seeds.py: no generated world at %s (build the target pcr_pro_sim_worlds)" % d)
    # Start from the hand-written seeds only: what this script wrote before goes.
    for target, names in OWNED.items():
        d = os.path.join(CORPUS, target)
        os.makedirs(d, exist_ok=True)
        for f in os.listdir(d):
            if f in names or target in ("lsd_keyframe", "lsd_graph"):
                os.remove(os.path.join(d, f))
    bundle_seeds()
    pcr = read("pcr_pro_two_agents.bag")
    lsd = read("lsd_slam_two_agents.bag")
    cloud_seeds(pcr)
    keyframe_seeds(pcr)
    lsd_seeds(lsd)
    for target in ("bundle", "ros_cloud", "ros_keyframe", "lsd_keyframe", "lsd_graph"):
        d = os.path.join(CORPUS, target)
        print(target + ": " + ", ".join("%s (%d B)" % (f, os.path.getsize(os.path.join(d, f)))
                                        for f in sorted(os.listdir(d))))


if __name__ == "__main__":
    main()
