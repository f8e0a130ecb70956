"""The tests' distance oracles and one reference for applying edits, in NumPy and SciPy,
independent of the server's kernels."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_cdt, distance_transform_edt


def oracle_distance(voxels: np.ndarray, cap: int) -> np.ndarray:
    """Capped Manhattan distance to the nearest solid voxel (scipy's taxicab transform), uint8;
    outside the world is air, so an all-air world is the cap everywhere."""
    if not voxels.any():
        return np.full(voxels.shape, cap, dtype=np.uint8)
    return np.minimum(distance_transform_cdt(voxels == 0, metric="taxicab"), cap).astype(np.uint8)


def field_distances(voxels: np.ndarray, metric: str, signed: bool, cap: int) -> np.ndarray:
    """(z, y, x) float distances in voxels between voxel centres, by scipy: to the nearest solid,
    capped; on solids 0, or in a signed world minus the distance to the nearest air voxel, the
    outside of the world counting as air (the transform of the inverted mask padded with air)."""
    def transform(mask: np.ndarray) -> np.ndarray:  # each True voxel's distance to the nearest False one
        if not (~mask).any():
            return np.full(mask.shape, float(cap))
        if metric == "euclidean":
            return distance_transform_edt(mask)
        return distance_transform_cdt(mask, metric="taxicab").astype(np.float64)

    solid = voxels != 0
    d = np.minimum(transform(~solid), cap)
    if not signed:
        return np.where(solid, 0.0, d)
    inside = transform(np.pad(solid, 1, constant_values=False))[1:-1, 1:-1, 1:-1]
    return np.where(solid, -np.minimum(inside, cap), d)


def apply_edits(voxels: np.ndarray, batch: list[dict]) -> None:
    """One batch on a (z, y, x) uint8 array in place, as the server defines the operations: boxes
    half-open and clipped to the world, spheres |p - c| <= r, voxel rows where a later row for the
    same voxel wins."""
    sz, sy, sx = voxels.shape
    for op in batch:
        if op["op"] == "voxels":
            rows = np.asarray(op["voxels"], dtype=np.int64).reshape(-1, 4)
            flat = np.ravel_multi_index((rows[:, 2], rows[:, 1], rows[:, 0]), voxels.shape)
            _, last = np.unique(flat[::-1], return_index=True)  # the last occurrence of each voxel
            keep = rows[::-1][last]
            voxels[keep[:, 2], keep[:, 1], keep[:, 0]] = keep[:, 3]
        elif op["op"] == "box":
            lo = np.clip(op["min"], 0, (sx, sy, sz))
            hi = np.clip(op["max"], 0, (sx, sy, sz))
            voxels[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]] = op["colour"]
        elif op["op"] == "sphere":
            z, y, x = np.ogrid[:sz, :sy, :sx]
            cx, cy, cz = op["center"]
            inside = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2 <= op["radius"] ** 2
            voxels[inside] = op["colour"]
        else:
            raise ValueError(op["op"])
