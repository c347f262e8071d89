#!/usr/bin/python3
"""Writes the generated seeds of the cloud-reader fuzz targets (test/fuzz/corpus/{pcd,csv}/).

Every point is made here (a small corner of a room: points on three planes with a slight wave,
unit normals and a curvature value), so that no seed comes from another project's data. The seeds
cover the header variants the readers accept: PCD ascii with extra fields (normals, curvature),
PCD binary, PCD binary_compressed (LZF, written as literal runs only, which is valid LZF), CSV
with a header, CSV without one, and whitespace-separated text.

Deterministic; standard library only:  /usr/bin/python3 test/fuzz/make_cloud_seeds.py
"""

import math
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
PCD_DIR = os.path.join(HERE, 'corpus', 'pcd')
CSV_DIR = os.path.join(HERE, 'corpus', 'csv')


def corner_points(n):
    """n points on the floor, a wall and a side wall of a 2 m corner, with unit normals."""
    pts = []
    for i in range(n):
        a = (i * 0.618034) % 1.0          # golden-ratio sequence: spread without randomness
        b = (i * 0.414214 + 0.3) % 1.0
        wave = 0.01 * math.sin(7.0 * a + 3.0 * b)
        plane = i % 3
        if plane == 0:
            p, nrm = (2.0 * a, 2.0 * b, wave), (0.0, 0.0, 1.0)
        elif plane == 1:
            p, nrm = (2.0 * a, wave, 2.0 * b), (0.0, 1.0, 0.0)
        else:
            p, nrm = (wave, 2.0 * a, 2.0 * b), (1.0, 0.0, 0.0)
        curvature = abs(wave) * 0.5
        pts.append((p, nrm, curvature))
    return pts


def pcd_header(fields, sizes, types, n, data):
    return ('# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS %s\nSIZE %s\nTYPE %s\nCOUNT %s\n'
            'WIDTH %d\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS %d\nDATA %s\n'
            % (' '.join(fields), ' '.join(sizes), ' '.join(types), ' '.join('1' for _ in fields), n, n, data))


def lzf_literal(data):
    """LZF stream made of literal runs only (control byte = run length - 1, at most 32 bytes)."""
    out = bytearray()
    for start in range(0, len(data), 32):
        chunk = data[start:start + 32]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)


def write(path, content):
    mode = 'wb' if isinstance(content, bytes) else 'w'
    with open(path, mode) as f:
        f.write(content)


def main():
    pts = corner_points(20)
    # PCD ascii with normals and curvature (extra fields the reader must skip).
    fields = ['x', 'y', 'z', 'normal_x', 'normal_y', 'normal_z', 'curvature']
    text = pcd_header(fields, ['4'] * 7, ['F'] * 7, len(pts), 'ascii')
    for p, nrm, c in pts:
        text += ' '.join('%.7g' % v for v in p + nrm + (c,)) + '\n'
    write(os.path.join(PCD_DIR, 'generated_ascii_normals.pcd'), text)

    xyz = [p for p, _, _ in corner_points(16)]
    header = pcd_header(['x', 'y', 'z'], ['4'] * 3, ['F'] * 3, len(xyz), 'binary')
    body = b''.join(struct.pack('<3f', *p) for p in xyz)  # array of structures
    write(os.path.join(PCD_DIR, 'generated_binary.pcd'), header.encode('ascii') + body)

    header = pcd_header(['x', 'y', 'z'], ['4'] * 3, ['F'] * 3, len(xyz), 'binary_compressed')
    raw = b''.join(struct.pack('<%df' % len(xyz), *[p[k] for p in xyz]) for k in range(3))  # structure of arrays
    packed = lzf_literal(raw)
    write(os.path.join(PCD_DIR, 'generated_binary_compressed.pcd'),
          header.encode('ascii') + struct.pack('<II', len(packed), len(raw)) + packed)

    rows = [(p + nrm) for p, nrm, _ in corner_points(30)]
    csv = ''.join(' , '.join('%.6g' % v for v in r[:3]) + ' , ' + ','.join('%.6g' % v for v in r[3:]) + '\n'
                  for r in rows)
    write(os.path.join(CSV_DIR, 'generated_header.csv'), 'x,y,z,nx,ny,nz\n' + csv)
    write(os.path.join(CSV_DIR, 'generated_noheader.csv'), csv)
    write(os.path.join(CSV_DIR, 'generated_spaces.txt'),
          ''.join(' '.join('%.6g' % v for v in r) + '\n' for r in rows))


if __name__ == '__main__':
    main()
