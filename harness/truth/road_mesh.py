"""A visual triangle mesh of a 3D road's surface (elevation and bank) for the renderer.

The surface z(s, e) = z_c(s) + e·tan φ_b(s) (``roadtruth.harness.truth.road``) is linear in the lateral offset e at
every station s, so a strip of two vertices per station (left and right edge) is exact across the
road; along it the stations are the road's own samples, every k-th one on long roads so that the
strip stays within a triangle budget the renderer draws cheaply. The mesh is for display only: the
car's contact uses :func:`roadtruth.harness.truth.road.road_surface`, never this mesh.
"""

from __future__ import annotations

import math

import numpy as np

from roadtruth.harness.truth.road import Road
from roadtruth.harness.truth.road_profile import COL_BANK, COL_PSI, COL_X, COL_Y, COL_Z

#: Most triangles of a road mesh (two per station interval).
MAX_ROAD_TRIANGLES = 4000


def road_surface_mesh(road: Road, half_width_m: float, *,
                      max_triangles: int = MAX_ROAD_TRIANGLES) -> tuple[np.ndarray, np.ndarray]:
    """Triangle strip of the road surface from ``-half_width_m`` (right) to ``+half_width_m`` (left).

    Parameters
    ----------
    road : the road (flat or 3D).
    half_width_m : half the width of the paved strip [m] (e.g. one lane width for both lanes).
    max_triangles : triangle budget; stations are every k-th road sample (plus the last one) with
        k the smallest stride that keeps ``2 * (stations - 1) <= max_triangles``.

    Returns
    -------
    vertices : (2 m, 3) float64 world points [m]; vertex 2 j is the left edge at station j,
        2 j + 1 the right edge.
    faces : (2 (m - 1), 3) int32 vertex indices, counter-clockwise seen from above (the normals
        point up, out of the road).
    """
    if not half_width_m > 0.0:
        raise ValueError(f"half_width_m must be > 0 (got {half_width_m})")
    if max_triangles < 2:
        raise ValueError(f"max_triangles must be >= 2 (got {max_triangles})")
    smp = road.samples
    n = smp.shape[0]
    stride = max(1, math.ceil((n - 1) / (max_triangles // 2)))
    rows = np.arange(0, n, stride)
    if rows[-1] != n - 1:
        rows = np.append(rows, n - 1)
    while 2 * (rows.size - 1) > max_triangles:  # the appended end station can tip the count over
        stride += 1
        rows = np.append(np.arange(0, n - 1, stride), n - 1)
    st = smp[rows]
    psi, tb = st[:, COL_PSI], np.tan(st[:, COL_BANK])
    lx, ly = -np.sin(psi), np.cos(psi)  # unit vector to the left of the centre line
    verts = np.empty((2 * rows.size, 3))
    for side, sign in ((0, 1.0), (1, -1.0)):
        e = sign * half_width_m
        verts[side::2, 0] = st[:, COL_X] + e * lx
        verts[side::2, 1] = st[:, COL_Y] + e * ly
        verts[side::2, 2] = st[:, COL_Z] + e * tb
    j = np.arange(rows.size - 1)
    left, right, left_n, right_n = 2 * j, 2 * j + 1, 2 * j + 2, 2 * j + 3
    faces = np.empty((2 * j.size, 3), dtype=np.int32)
    faces[0::2] = np.column_stack([right, right_n, left_n])
    faces[1::2] = np.column_stack([right, left_n, left])
    return verts, faces
