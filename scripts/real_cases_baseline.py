#!/usr/bin/python3
"""Runs pcr_pro_merge on every real two-agent case of BUILD/real_cases and prints a Markdown table
of its errors against each case's truth (docs/FORMATS.md).

Errors: rotation [deg]; translation = distance between where the estimate and the truth put the
source cloud's centroid, in % of the target map's extent (diagonal of the 5-95 % box of the target
cloud), so that it does not depend on where a map's arbitrary origin lies; scale = estimate / truth
- 1 [%]. Next to them, the truth's own accuracy (truth_accuracy in truth.yaml) in the same units.

Usage: /usr/bin/python3 scripts/real_cases_baseline.py [BUILD_DIR] [--config FILE]
Needs Debian's python3-yaml. Takes a few minutes (one merge per case, serially).
"""

import argparse
import math
import os
import struct
import subprocess
import sys
import time

import yaml


def quat_to_matrix(q):
    x, y, z, w = q
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]


def apply(sim, p):
    s, r, t = sim
    return [s * sum(r[i][k] * p[k] for k in range(3)) + t[i] for i in range(3)]


def sim_from(node):
    return (float(node['scale']), quat_to_matrix([float(v) for v in node['rotation']]),
            [float(v) for v in node['translation']])


def rotation_deg(ra, rb):
    trace = sum(ra[i][k] * rb[i][k] for i in range(3) for k in range(3))  # trace(ra rb^T)
    return math.degrees(math.acos(max(-1.0, min(1.0, (trace - 1.0) / 2.0))))


def read_pcd_xyz(path):
    """x y z of a binary PCD with float x y z first (what writePcd writes)."""
    with open(path, 'rb') as f:
        data = f.read()
    header_end = data.index(b'DATA binary\n') + len(b'DATA binary\n')
    header = dict(line.split(' ', 1) for line in data[:header_end].decode('ascii').splitlines()
                  if line and not line.startswith('#'))
    if header.get('FIELDS', '').split()[:3] != ['x', 'y', 'z']:
        sys.exit('%s: expected fields x y z' % path)
    n = int(header['POINTS'])
    stride = sum(int(v) for v in header['SIZE'].split())
    body = data[header_end:]
    return [struct.unpack_from('<3f', body, i * stride) for i in range(n)]


def robust_diagonal(points):
    lo, hi = [], []
    for axis in range(3):
        v = sorted(p[axis] for p in points)
        lo.append(v[len(v) // 20])
        hi.append(v[len(v) - 1 - len(v) // 20])
    return math.dist(lo, hi)


def merge(binary, case_dir, truth, config):
    args = [binary, '--source', os.path.join(case_dir, truth['source']),
            '--target', os.path.join(case_dir, truth['target'])]
    if config:
        args += ['--config', config]
    start = time.monotonic()
    run = subprocess.run(args, capture_output=True, text=True)
    seconds = time.monotonic() - start
    if run.returncode == 2:
        sys.exit('%s: pcr_pro_merge: %s' % (case_dir, run.stderr.strip()))
    return yaml.safe_load(run.stdout), seconds


def row(build, case, config):
    case_dir = os.path.join(build, 'real_cases', case['path'])
    truth = yaml.safe_load(open(os.path.join(case_dir, 'truth.yaml')))
    result, seconds = merge(os.path.join(build, 'devel', 'lib', 'pcr_pro', 'pcr_pro_merge'), case_dir, truth, config)
    target = read_pcd_xyz(os.path.join(case_dir, truth['target'], 'map.pcd'))
    source = read_pcd_xyz(os.path.join(case_dir, truth['source'], 'map.pcd'))
    extent = robust_diagonal(target)
    centroid = [sum(p[k] for p in source) / len(source) for k in range(3)]
    true_sim = sim_from(truth['S_target_source'])
    acc = truth.get('truth_accuracy', {})
    out = {'case': case['path'], 'overlap': truth['overlap'], 'status': result['status'], 'seconds': seconds,
           'angle': case['angle_deg'], 'truth_rot': acc.get('rotation_deg'),
           'truth_trans': 100.0 * acc.get('translation', 0.0) / extent, 'truth_scale': 100.0 * acc.get('scale_rel', 0.0)}
    if 'scale' in result:
        est = (float(result['scale']), quat_to_matrix([float(v) for v in result['rotation']]),
               [float(v) for v in result['translation']])
        out['rot'] = rotation_deg(est[1], true_sim[1])
        out['trans'] = 100.0 * math.dist(apply(est, centroid), apply(true_sim, centroid)) / extent
        out['scale'] = 100.0 * (est[0] / true_sim[0] - 1.0)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('build', nargs='?', default='build')
    parser.add_argument('--config', help='merge configuration passed to pcr_pro_merge')
    args = parser.parse_args()
    index = yaml.safe_load(open(os.path.join(args.build, 'real_cases', 'index.yaml')))
    print('| case | overlap | ref. angle [deg] | status | rotation [deg] | translation [% extent] | scale [%] '
          '| truth accuracy (rot / trans % / scale %) | time [s] |')
    print('|---|---|---|---|---|---|---|---|---|')
    for case in index['cases']:
        r = row(args.build, case, args.config)
        err = ('%.2f | %.2f | %+.2f' % (r['rot'], r['trans'], r['scale'])) if 'rot' in r else '– | – | –'
        accuracy = '%.2g / %.2g / %.2g' % (r['truth_rot'], r['truth_trans'], r['truth_scale']) if r['overlap'] else '–'
        print('| %s | %s | %.1f | %s | %s | %s | %.1f |' % (r['case'], 'yes' if r['overlap'] else 'no', r['angle'],
                                                         r['status'], err, accuracy, r['seconds']))
        sys.stdout.flush()


if __name__ == '__main__':
    main()
