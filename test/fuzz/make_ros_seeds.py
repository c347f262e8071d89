#!/usr/bin/env python3
"""Writes the seed corpus of the ROS message fuzz targets (test/fuzz/corpus/{ros_cloud,
ros_keyframe,lsd_keyframe,lsd_graph}/) by cutting small messages out of the shipped bags
(test/data/bags): the first points of a map cloud, 16x12 crops of real keyframes (with their
intrinsics moved to the crop) and the real LSD-SLAM graph messages. Each seed is one message in
ROS serialization, exactly the bytes a subscriber deserializes. Deterministic.

Usage: /usr/bin/python3 test/fuzz/make_ros_seeds.py   (Debian's python3: it needs python3-rosbag)
"""
import copy
import io
import os
import struct

import rosbag

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
BAGS = os.path.join(ROOT, "test", "data", "bags")
CORPUS = os.path.join(ROOT, "test", "fuzz", "corpus")
CROP_W, CROP_H = 16, 12


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


def keyframe_seeds(msgs):
    kfs = [m for t, m in msgs if t.endswith("/keyframes")]
    # agent_a keyframe 1: mono8 + 16UC1 depth, centre crop.
    a = copy.deepcopy(kfs[0])
    x0, y0 = a.image.width // 2, a.image.height // 2
    crop_image(a.image, x0, y0, CROP_W, CROP_H, 1)
    crop_image(a.depth, x0, y0, CROP_W, CROP_H, 2)
    crop_camera(a.camera_info, x0, y0, CROP_W, CROP_H)
    write("ros_keyframe", "agent_a_kf1_mono8_16uc1.msg", a)

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
    write("ros_keyframe", "agent_a_kf1_bgra8_nodepth.msg", c)


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


def main():
    pcr = read("pcr_pro_two_agents.bag")
    lsd = read("lsd_slam_two_agents.bag")
    cloud_seeds(pcr)
    keyframe_seeds(pcr)
    lsd_seeds(lsd)
    for target in ("ros_cloud", "ros_keyframe", "lsd_keyframe", "lsd_graph"):
        d = os.path.join(CORPUS, target)
        print(target + ": " + ", ".join("%s (%d B)" % (f, os.path.getsize(os.path.join(d, f)))
                                        for f in sorted(os.listdir(d))))


if __name__ == "__main__":
    main()
