#!/usr/bin/python3
"""Builds the two-agent map bundles under test/data/bundles from test/data/slambook2_ch5_rgbd.

Five real Kinect frames (NYU Depth V2, via slambook2 ch5) become the maps of two simulated
monocular-SLAM agents. Each agent gets:
  * keyframes: 8-bit grey PNG images (and, where the case has depth, 16-bit depth PNG in mm);
  * a semi-dense map cloud like LSD-SLAM's: high-gradient pixels (Sobel magnitude above a
    threshold, away from depth discontinuities, randomly thinned with a fixed seed) back-projected
    with the measured depth into the world frame of pose.txt and then into the agent's own map
    frame by a per-agent similarity G_agent (world -> agent map: scale, rotation, translation);
  * keyframe poses camera -> agent map: scale = s, R = R_agent * R_wc,
    position = s * R_agent * t_wc + t_agent, so that p_map = scale * R * p_cam + position holds
    with p_cam in metres.

Cases (target = agent_a, source = agent_b):
  depth/      agent_a = frames 1, 2, 4; agent_b = frames 3, 5; full 640x480 keyframes with depth.
  nodepth/    the same two agents without depth images: bundle.yaml files only, naming the
              images and map clouds of depth/ (paths relative to the bundle directory).
  sharedworld/ the keyframes of depth/ (named, not copied); both map clouds drawn from one world
              cloud, the semi-dense points of all five frames, each point given to an agent whose
              frames see it (at random when both do): independent samples of the same surfaces,
              for which the truth is exact also with respect to the clouds' geometry.
  nooverlap/  agent_a = right half (u >= 320) of frame 1; agent_b = left halves (u < 320) of
              frames 4 and 5. No 3D point seen in one half is inside the other half's view
              (checked with the depth images and poses), so a correct pipeline must refuse it.

Each case gets a truth.yaml with S_target_source = G_a * G_b^-1. The script also writes
overlap_checks.yaml: for every cross-agent keyframe pair the SIFT + RANSAC essential-matrix inlier
count and the depth-based view overlap, and for every case the fraction of source-cloud points
that land within 5 cm of a target-cloud point under the true transform.

Deterministic (fixed seeds). Needs Debian's python3-numpy, python3-opencv and python3-yaml:
    /usr/bin/python3 scripts/make_bundles.py [--output DIR]
"""

import argparse
import math
import os
import shutil
import sys

import cv2
import numpy as np
import yaml

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SOURCE_DIR = os.path.join(REPO, 'test', 'data', 'slambook2_ch5_rgbd')
DEFAULT_OUTPUT = os.path.join(REPO, 'test', 'data', 'bundles')

# Camera of the source frames (slambook2 ch5/rgbd/joinMap.cpp).
FX, FY, CX, CY = 518.0, 519.0, 325.5, 253.5
WIDTH, HEIGHT = 640, 480
DEPTH_SCALE = 1000.0  # depth PNG value per metre (the source PGMs are in millimetres)

# Semi-dense selection (LSD-SLAM keeps pixels with a high image gradient).
GRADIENT_THRESHOLD = 60.0   # Sobel 3x3 magnitude on the 0..255 grey image
KEEP_FRACTION = 0.5         # random thinning of the selected pixels
MIN_DEPTH_M, MAX_DEPTH_M = 0.3, 10.0
MAX_LOCAL_DEPTH_STEP = 0.05  # drop pixels whose 3x3 depth range exceeds 5 % of their depth
BORDER_PX = 8               # ignore the white border of the NYU frames
SEED = 20240531

# SIFT check: OpenCV SIFT, FLANN k-d tree, Lowe ratio, RANSAC essential matrix.
SIFT_RATIO = 0.7
RANSAC_THRESHOLD_PX = 1.0
RANSAC_CONFIDENCE = 0.999
CLOUD_OVERLAP_RADIUS_M = 0.05  # in target (agent_a) map units = metres

POSE_NOTE = ('S_target_source is exact by construction, but the underlying camera poses '
             '(slambook2 ch5/rgbd/pose.txt) are approximate, not motion capture: about 1 deg / a few cm '
             '(see slambook2_ch5_rgbd/SOURCE.txt). The two agents therefore agree with each other only '
             'that well, and an estimate from images and clouds can differ from the truth by as much: '
             'compare with loose tolerances.')


# ---- small geometry helpers ------------------------------------------------------------------

def quat_to_matrix(q):
    """Rotation matrix of a quaternion [x, y, z, w] (normalised here)."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_to_quat(r):
    """Quaternion [x, y, z, w] with w >= 0 of a rotation matrix."""
    t = np.trace(r)
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = [0.0, 0.0, 0.0, (r[k, j] - r[j, k]) / s]
        q[i] = 0.25 * s
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def axis_angle(axis, degrees):
    axis = np.asarray(axis, dtype=float)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(degrees)
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * (k @ k)


class Sim3:
    """p' = s * R * p + t"""

    def __init__(self, s, r, t):
        self.s, self.r, self.t = float(s), np.asarray(r, dtype=float), np.asarray(t, dtype=float)

    def apply(self, pts):  # pts: N x 3
        return self.s * pts @ self.r.T + self.t

    def __mul__(self, o):
        return Sim3(self.s * o.s, self.r @ o.r, self.s * self.r @ o.t + self.t)

    def inverse(self):
        return Sim3(1.0 / self.s, self.r.T, -(self.r.T @ self.t) / self.s)


# World -> agent map similarities. Agent A keeps metres; agent B has 0.4 map units per metre, a
# 120 degree rotation and a large offset, as two independently initialised monocular maps would.
G_AGENT = {
    'agent_a': Sim3(1.0, axis_angle([0.3, 1.0, -0.2], 25.0), [0.4, -0.1, 0.7]),
    'agent_b': Sim3(0.4, axis_angle([-0.5, 0.8, 0.6], 120.0), [2.5, -1.2, 3.0]),
}


# ---- source data ----------------------------------------------------------------------------

def load_source():
    poses = np.loadtxt(os.path.join(SOURCE_DIR, 'pose.txt'))
    frames = {}
    for i in range(1, 6):
        colour = cv2.imread(os.path.join(SOURCE_DIR, 'color', '%d.png' % i), cv2.IMREAD_COLOR)
        depth = cv2.imread(os.path.join(SOURCE_DIR, 'depth', '%d.pgm' % i), cv2.IMREAD_UNCHANGED)
        if colour is None or depth is None or depth.dtype != np.uint16:
            sys.exit('make_bundles: cannot read frame %d of %s' % (i, SOURCE_DIR))
        p = poses[i - 1]
        frames[i] = {
            'grey': cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY),
            'depth_mm': depth,
            'T_wc': Sim3(1.0, quat_to_matrix(p[3:7]), p[0:3]),  # camera -> world
            'pose_line': p,
        }
    return frames


class Crop:
    """A column/row window of the 640x480 frames and the matching pinhole camera."""

    def __init__(self, x0=0, y0=0, width=WIDTH, height=HEIGHT):
        self.x0, self.y0, self.width, self.height = x0, y0, width, height

    def image(self, img):
        return img[self.y0:self.y0 + self.height, self.x0:self.x0 + self.width]

    def camera(self):
        return {'fx': FX, 'fy': FY, 'cx': CX - self.x0, 'cy': CY - self.y0,
                'width': self.width, 'height': self.height}


def semi_dense_points(frame, crop, rng):
    """High-gradient pixels of the crop with valid, locally smooth depth -> world points (N x 3)."""
    grey = frame['grey'].astype(np.float32)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.sqrt(gx * gx + gy * gy)
    depth = frame['depth_mm'].astype(np.float32)
    kernel = np.ones((3, 3), np.uint8)
    # every 3x3 neighbour has depth, and the neighbourhood spans no depth discontinuity
    all_valid = cv2.erode((depth > 0).astype(np.uint8), kernel) > 0
    local_range = cv2.dilate(depth, kernel) - cv2.erode(depth, kernel)
    smooth = all_valid & (local_range < MAX_LOCAL_DEPTH_STEP * depth)
    z = depth / DEPTH_SCALE
    select = (magnitude > GRADIENT_THRESHOLD) & smooth & (z > MIN_DEPTH_M) & (z < MAX_DEPTH_M)
    border = np.zeros_like(select)
    border[BORDER_PX:HEIGHT - BORDER_PX, BORDER_PX:WIDTH - BORDER_PX] = True
    window = np.zeros_like(select)
    window[crop.y0:crop.y0 + crop.height, crop.x0:crop.x0 + crop.width] = True
    select &= border & window
    v, u = np.nonzero(select)
    keep = rng.random(len(u)) < KEEP_FRACTION
    u, v = u[keep], v[keep]
    zz = z[v, u].astype(float)
    p_cam = np.stack([(u - CX) / FX * zz, (v - CY) / FY * zz, zz], axis=1)
    return frame['T_wc'].apply(p_cam)


# ---- writers --------------------------------------------------------------------------------

def write_pcd(path, pts):
    pts = np.ascontiguousarray(pts, dtype='<f4')
    header = ('# .PCD v0.7 - Point Cloud Data file format\n'
              'VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n'
              'WIDTH %d\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS %d\nDATA binary\n'
              % (len(pts), len(pts)))
    with open(path, 'wb') as f:
        f.write(header.encode('ascii'))
        f.write(pts.tobytes())


def fmt(x):
    return repr(float(round(float(x), 12))) if abs(x) > 1e-15 else '0.0'


def fmt_list(values):
    return '[' + ', '.join(fmt(v) for v in values) + ']'


def sim3_yaml(g, indent):
    pad = ' ' * indent
    return ('%sscale: %s\n%srotation: %s  # quaternion x y z w\n%stranslation: %s\n'
            % (pad, fmt(g.s), pad, fmt_list(matrix_to_quat(g.r)), pad, fmt_list(g.t)))


def write_bundle_yaml(path, agent, camera, cloud, keyframes, comment):
    lines = ['# %s' % c for c in comment]
    lines += ['frame_id: %s/map' % agent, 'cloud: %s' % cloud, 'camera:']
    for key in ('fx', 'fy', 'cx', 'cy'):
        lines.append('  %s: %s' % (key, fmt(camera[key])))
    lines += ['  width: %d' % camera['width'], '  height: %d' % camera['height'], 'keyframes:']
    for kf in keyframes:
        lines += ['  - id: %d' % kf['id'], '    image: %s' % kf['image'], '    pose:',
                  '      position: %s' % fmt_list(kf['position']),
                  '      orientation: %s' % fmt_list(kf['orientation']),
                  '      scale: %s' % fmt(kf['scale'])]
        if 'depth' in kf:
            lines += ['    depth: %s' % kf['depth'], '    depth_scale: %s' % fmt(DEPTH_SCALE)]
    with open(path, 'w') as f:
        f.write('\n'.join(lines) + '\n')


# ---- checks ---------------------------------------------------------------------------------

def sift_inliers(img_a, img_b, camera_a, camera_b):
    """SIFT + FLANN ratio test + RANSAC essential matrix on normalised image coordinates."""
    cv2.setRNGSeed(SEED)
    sift = cv2.SIFT_create()
    ka, da = sift.detectAndCompute(img_a, None)
    kb, db = sift.detectAndCompute(img_b, None)
    result = {'keypoints': [len(ka), len(kb)], 'ratio_matches': 0, 'essential_inliers': 0}
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return result
    matcher = cv2.FlannBasedMatcher(dict(algorithm=1, trees=5), dict(checks=64))
    knn = matcher.knnMatch(da, db, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < SIFT_RATIO * m[1].distance]
    result['ratio_matches'] = len(good)
    if len(good) < 5:
        return result

    def normalised(kps, idx, cam):
        pts = np.float64([kps[i].pt for i in idx])
        return np.stack([(pts[:, 0] - cam['cx']) / cam['fx'], (pts[:, 1] - cam['cy']) / cam['fy']], axis=1)

    pa = normalised(ka, [m.queryIdx for m in good], camera_a)
    pb = normalised(kb, [m.trainIdx for m in good], camera_b)
    focal = 0.5 * (FX + FY)
    e, mask = cv2.findEssentialMat(pa, pb, np.eye(3), cv2.RANSAC, RANSAC_CONFIDENCE,
                                   RANSAC_THRESHOLD_PX / focal)
    if e is None:
        return result
    best = 0
    for k in range(0, e.shape[0], 3):  # the 5-point solver may return several solutions
        n, _, _, _ = cv2.recoverPose(e[k:k + 3], pa, pb, np.eye(3), mask=mask.copy())
        best = max(best, int(n))
    result['essential_inliers'] = best
    return result


def view_overlap(frame_a, crop_a, frame_b, crop_b, step=2):
    """Fraction of crop_a pixels with depth whose 3D point projects into crop_b (z > 0).

    No occlusion test, so the number can only over-state the overlap.
    """
    depth = frame_a['depth_mm'][crop_a.y0:crop_a.y0 + crop_a.height:step,
                                crop_a.x0:crop_a.x0 + crop_a.width:step].astype(float) / DEPTH_SCALE
    v, u = np.nonzero(depth > 0)
    z = depth[v, u]
    u = u * step + crop_a.x0
    v = v * step + crop_a.y0
    p_w = frame_a['T_wc'].apply(np.stack([(u - CX) / FX * z, (v - CY) / FY * z, z], axis=1))
    p_b = frame_b['T_wc'].inverse().apply(p_w)
    with np.errstate(divide='ignore', invalid='ignore'):
        ub = FX * p_b[:, 0] / p_b[:, 2] + CX
        vb = FY * p_b[:, 1] / p_b[:, 2] + CY
    inside = ((p_b[:, 2] > 0) & (ub >= crop_b.x0) & (ub < crop_b.x0 + crop_b.width) &
              (vb >= crop_b.y0) & (vb < crop_b.y0 + crop_b.height))
    return float(inside.mean()) if len(inside) else 0.0


def cloud_overlap(target, source_in_target, radius):
    """Fraction of source points with a target point within `radius` (voxel hash, exact test)."""
    def pack(keys):  # collisions only cost extra distance tests below
        return (keys[:, 0] * 1000003 + keys[:, 1]) * 1000033 + keys[:, 2]

    packed = pack(np.floor(target / radius).astype(np.int64))
    order = np.argsort(packed, kind='stable')
    packed, pts_sorted = packed[order], target[order]
    keys_s = np.floor(source_in_target / radius).astype(np.int64)
    hit = np.zeros(len(source_in_target), dtype=bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                pk = pack(keys_s + np.array([dx, dy, dz]))
                lo = np.searchsorted(packed, pk, side='left')
                hi = np.searchsorted(packed, pk, side='right')
                todo = np.nonzero((hi > lo) & ~hit)[0]
                for i in todo:
                    d = np.linalg.norm(pts_sorted[lo[i]:hi[i]] - source_in_target[i], axis=1)
                    if d.min() <= radius:
                        hit[i] = True
    return float(hit.mean())


# ---- cases ----------------------------------------------------------------------------------

CASES = {
    'depth': {'frames': {'agent_a': [1, 2, 4], 'agent_b': [3, 5]},
              'crop': {'agent_a': Crop(), 'agent_b': Crop()}, 'depth': True, 'overlap': True},
    'nooverlap': {'frames': {'agent_a': [1], 'agent_b': [4, 5]},
                  'crop': {'agent_a': Crop(x0=320, width=320), 'agent_b': Crop(x0=0, width=320)},
                  'depth': True, 'overlap': False},
}


def build_agent(out_dir, case, agent, frames):
    spec = CASES[case]
    crop = spec['crop'][agent]
    g = G_AGENT[agent]
    bundle_dir = os.path.join(out_dir, case, agent)
    os.makedirs(os.path.join(bundle_dir, 'keyframes'))
    keyframes, clouds, images = [], [], {}
    for fid in spec['frames'][agent]:
        frame = frames[fid]
        rng = np.random.default_rng([SEED, fid, crop.x0, crop.y0, crop.width, crop.height])
        clouds.append(g.apply(semi_dense_points(frame, crop, rng)))
        grey = np.ascontiguousarray(crop.image(frame['grey']))
        images[fid] = grey
        cv2.imwrite(os.path.join(bundle_dir, 'keyframes', '%d.png' % fid), grey)
        pose = g * frame['T_wc']  # camera -> agent map
        kf = {'id': fid, 'image': 'keyframes/%d.png' % fid, 'position': pose.t,
              'orientation': matrix_to_quat(pose.r), 'scale': pose.s}
        if spec['depth']:
            depth = np.ascontiguousarray(crop.image(frame['depth_mm']))
            cv2.imwrite(os.path.join(bundle_dir, 'keyframes', '%d_depth.png' % fid), depth)
            kf['depth'] = 'keyframes/%d_depth.png' % fid
        keyframes.append(kf)
    cloud = np.concatenate(clouds, axis=0)
    write_pcd(os.path.join(bundle_dir, 'map.pcd'), cloud)
    comment = ['Generated by scripts/make_bundles.py from test/data/slambook2_ch5_rgbd, frames: %s.'
               % ', '.join(str(f) for f in spec['frames'][agent]),
               'Map frame = world of pose.txt mapped by %s in ../truth.yaml.'
               % ('world_to_target' if agent == 'agent_a' else 'world_to_source')]
    if crop.width != WIDTH or crop.height != HEIGHT:
        comment.append('Keyframes are the window u in [%d, %d), v in [%d, %d) of the 640x480 frames.'
                       % (crop.x0, crop.x0 + crop.width, crop.y0, crop.y0 + crop.height))
    write_bundle_yaml(os.path.join(bundle_dir, 'bundle.yaml'), agent, crop.camera(), 'map.pcd',
                      keyframes, comment)
    return {'cloud': cloud, 'keyframes': keyframes, 'images': images, 'camera': crop.camera(),
            'crop': crop}


def write_nodepth(out_dir, depth_agents):
    for agent, info in depth_agents.items():
        bundle_dir = os.path.join(out_dir, 'nodepth', agent)
        os.makedirs(bundle_dir)
        keyframes = []
        for kf in info['keyframes']:
            kf = {k: v for k, v in kf.items() if k not in ('depth',)}
            kf['image'] = '../../depth/%s/%s' % (agent, kf['image'])
            keyframes.append(kf)
        comment = ['Generated by scripts/make_bundles.py: the %s bundle of ../../depth without its' % agent,
                   'depth images (keyframe depth must come from the map cloud). It names the files of',
                   '../../depth/%s (paths are relative to this directory).' % agent]
        write_bundle_yaml(os.path.join(bundle_dir, 'bundle.yaml'), agent, info['camera'],
                          '../../depth/%s/map.pcd' % agent, keyframes, comment)


def visible_in(frame, pts_world):
    """Mask of world points that frame sees: inside the image (off the border), in front, and
    within 5 % of the frame's measured depth at their pixel (not occluded, not behind)."""
    p = frame['T_wc'].inverse().apply(pts_world)
    z = p[:, 2]
    with np.errstate(divide='ignore', invalid='ignore'):
        u = np.round(p[:, 0] / z * FX + CX)
        v = np.round(p[:, 1] / z * FY + CY)
    inside = (z > 0) & (u >= BORDER_PX) & (u < WIDTH - BORDER_PX) & (v >= BORDER_PX) & (v < HEIGHT - BORDER_PX)
    ok = np.zeros(len(pts_world), dtype=bool)
    ui, vi = u[inside].astype(int), v[inside].astype(int)
    measured = frame['depth_mm'][vi, ui].astype(float) / DEPTH_SCALE
    ok[np.nonzero(inside)[0]] = (measured > 0) & (np.abs(measured - z[inside]) < 0.05 * z[inside])
    return ok


def write_sharedworld(out_dir, frames, depth_agents):
    """Both agents sample one world cloud: the semi-dense points of all five frames (as in
    depth/), each given to an agent that sees it, at random when both do. The clouds are then
    independent samples of the same surfaces, so the truth is exact for their geometry too
    (in depth/ each agent's cloud carries its own frames' pose errors)."""
    spec = CASES['depth']
    world, owner = [], []
    for agent in ('agent_a', 'agent_b'):
        for fid in spec['frames'][agent]:
            crop = spec['crop'][agent]
            rng = np.random.default_rng([SEED, fid, crop.x0, crop.y0, crop.width, crop.height])
            world.append(semi_dense_points(frames[fid], crop, rng))
    world = np.concatenate(world, axis=0)
    sees = {agent: np.zeros(len(world), dtype=bool) for agent in ('agent_a', 'agent_b')}
    for agent in sees:
        for fid in spec['frames'][agent]:
            sees[agent] |= visible_in(frames[fid], world)
    rng = np.random.default_rng([SEED, 7])
    to_a = sees['agent_a'] & (~sees['agent_b'] | (rng.random(len(world)) < 0.5))
    to_b = sees['agent_b'] & ~to_a
    clouds = {'agent_a': G_AGENT['agent_a'].apply(world[to_a]), 'agent_b': G_AGENT['agent_b'].apply(world[to_b])}
    agents = {}
    for agent, info in depth_agents.items():
        bundle_dir = os.path.join(out_dir, 'sharedworld', agent)
        os.makedirs(bundle_dir)
        write_pcd(os.path.join(bundle_dir, 'map.pcd'), clouds[agent])
        keyframes = []
        for kf in info['keyframes']:
            kf = dict(kf)
            kf['image'] = '../../depth/%s/%s' % (agent, kf['image'])
            kf['depth'] = '../../depth/%s/%s' % (agent, kf['depth'])
            keyframes.append(kf)
        comment = ['Generated by scripts/make_bundles.py: the keyframes of ../../depth/%s (named through' % agent,
                   'relative paths) with a map cloud drawn from the world cloud of all five frames: each',
                   'semi-dense point goes to an agent whose frames see it, at random when both agents do.']
        write_bundle_yaml(os.path.join(bundle_dir, 'bundle.yaml'), agent, info['camera'], 'map.pcd', keyframes,
                          comment)
        agents[agent] = dict(info, cloud=clouds[agent])
    return agents


def write_truth(out_dir, case, frames, agents, overlap, keyframe_note):
    g_a, g_b = G_AGENT['agent_a'], G_AGENT['agent_b']
    s_ab = g_a * g_b.inverse()
    text = ('# Ground truth of case "%s" (generated by scripts/make_bundles.py).\n'
            '# Similarities map p -> scale * R(rotation) * p + translation.\n'
            'case: %s\n'
            'target: agent_a\n'
            'source: agent_b\n'
            '# %s\n'
            'overlap: %s\n'
            '# maps agent_b map points into the agent_a map (agent_a units): G_a * G_b^-1\n'
            'S_target_source:\n%s'
            '# world (pose.txt frame, metres) -> agent_a map\n'
            'world_to_target:\n%s'
            '# world (pose.txt frame, metres) -> agent_b map\n'
            'world_to_source:\n%s'
            'keyframes:\n  agent_a: %s\n  agent_b: %s\n'
            '# camera -> world poses of the source frames (pose.txt: tx ty tz qx qy qz qw)\n'
            'world_poses:\n'
            % (case, case, keyframe_note, 'true' if overlap else 'false', sim3_yaml(s_ab, 2),
               sim3_yaml(g_a, 2), sim3_yaml(g_b, 2),
               '[' + ', '.join(str(k['id']) for k in agents['agent_a']['keyframes']) + ']',
               '[' + ', '.join(str(k['id']) for k in agents['agent_b']['keyframes']) + ']'))
    ids = sorted({k['id'] for a in agents.values() for k in a['keyframes']})
    for fid in ids:
        p = frames[fid]['pose_line']
        text += '  %d: {position: %s, orientation: %s}\n' % (fid, fmt_list(p[0:3]), fmt_list(p[3:7]))
    text += 'note: "%s"\n' % POSE_NOTE
    path = os.path.join(out_dir, case, 'truth.yaml')
    with open(path, 'w') as f:
        f.write(text)
    return s_ab


def check_case(case, frames, agents, s_ab):
    a, b = agents['agent_a'], agents['agent_b']
    pairs = []
    for ka in a['keyframes']:
        for kb in b['keyframes']:
            sift = sift_inliers(a['images'][ka['id']], b['images'][kb['id']], a['camera'], b['camera'])
            pairs.append({
                'target_keyframe': ka['id'], 'source_keyframe': kb['id'],
                'sift_keypoints': sift['keypoints'],
                'ratio_matches': sift['ratio_matches'],
                'essential_inliers': sift['essential_inliers'],
                'view_overlap_target_in_source': round(view_overlap(frames[ka['id']], a['crop'], frames[kb['id']], b['crop']), 4),
                'view_overlap_source_in_target': round(view_overlap(frames[kb['id']], b['crop'], frames[ka['id']], a['crop']), 4),
            })
    frac = cloud_overlap(a['cloud'], s_ab.apply(b['cloud']), CLOUD_OVERLAP_RADIUS_M)
    return {'cloud_points': {'agent_a': int(len(a['cloud'])), 'agent_b': int(len(b['cloud']))},
            'source_points_within_5cm_of_target': round(frac, 4), 'keyframe_pairs': pairs}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--output', default=DEFAULT_OUTPUT, help='output directory (default %(default)s)')
    args = parser.parse_args()
    out_dir = os.path.abspath(args.output)
    os.makedirs(out_dir, exist_ok=True)
    for case in ('depth', 'nodepth', 'nooverlap', 'sharedworld'):
        shutil.rmtree(os.path.join(out_dir, case), ignore_errors=True)

    frames = load_source()
    # The frames come from slambook2 (MIT): its licence travels with the derived data.
    shutil.copyfile(os.path.join(SOURCE_DIR, 'LICENSE'), os.path.join(out_dir, 'LICENSE'))
    checks = {}
    notes = {
        'depth': 'agent_a = frames 1, 2, 4; agent_b = frames 3, 5 (pairs 2-3, 3-4, 4-5 overlap best)',
        'nodepth': 'same agents and files as depth/, without depth images',
        'nooverlap': 'agent_a = frame 1, u >= 320; agent_b = frames 4, 5, u < 320: views do not overlap',
        'sharedworld': 'keyframes of depth/; both clouds sampled from the world cloud of all five frames',
    }
    built = {}
    for case in ('depth', 'nooverlap'):
        agents = {agent: build_agent(out_dir, case, agent, frames) for agent in ('agent_a', 'agent_b')}
        built[case] = agents
        s_ab = write_truth(out_dir, case, frames, agents, CASES[case]['overlap'], notes[case])
        checks[case] = check_case(case, frames, agents, s_ab)
    write_nodepth(out_dir, built['depth'])
    write_truth(out_dir, 'nodepth', frames, built['depth'], True, notes['nodepth'])
    shared = write_sharedworld(out_dir, frames, built['depth'])
    s_ab = write_truth(out_dir, 'sharedworld', frames, shared, True, notes['sharedworld'])
    frac = cloud_overlap(shared['agent_a']['cloud'], s_ab.apply(shared['agent_b']['cloud']), CLOUD_OVERLAP_RADIUS_M)
    checks['sharedworld'] = {'cloud_points': {'agent_a': int(len(shared['agent_a']['cloud'])),
                                              'agent_b': int(len(shared['agent_b']['cloud']))},
                             'source_points_within_5cm_of_target': round(frac, 4), 'keyframe_pairs': []}

    with open(os.path.join(out_dir, 'overlap_checks.yaml'), 'w') as f:
        f.write('# Written by scripts/make_bundles.py (OpenCV %s). Per case: map cloud sizes, the fraction\n'
                '# of agent_b cloud points within %.2f m of an agent_a point under the true transform, and per\n'
                '# cross-agent keyframe pair: SIFT keypoints, ratio-test matches (ratio %.1f), inliers of a\n'
                '# RANSAC essential matrix (%.1f px, confidence %.3f, after the cheirality check) and the\n'
                '# fraction of pixels with depth of one view that project into the other (no occlusion test).\n'
                '# nodepth uses the same images and clouds as depth.\n'
                % (cv2.__version__, CLOUD_OVERLAP_RADIUS_M, SIFT_RATIO, RANSAC_THRESHOLD_PX, RANSAC_CONFIDENCE))
        yaml.safe_dump(checks, f, default_flow_style=None, sort_keys=False, width=100)

    for case, c in checks.items():
        print('%s: cloud points agent_a %d, agent_b %d; agent_b points within 5 cm of agent_a: %.1f %%'
              % (case, c['cloud_points']['agent_a'], c['cloud_points']['agent_b'],
                 100.0 * c['source_points_within_5cm_of_target']))
        for p in c['keyframe_pairs']:
            print('  target %d / source %d: keypoints %s, ratio matches %d, essential inliers %d, '
                  'view overlap %.3f / %.3f' % (p['target_keyframe'], p['source_keyframe'], p['sift_keypoints'],
                                              p['ratio_matches'], p['essential_inliers'],
                                              p['view_overlap_target_in_source'], p['view_overlap_source_in_target']))
    print('written to %s' % out_dir)


if __name__ == '__main__':
    main()
