"""What the benchmarks check fields against: scipy's transforms, an implementation independent
of every kernel here, capped and signed as a world stores them."""

from __future__ import annotations

import numpy as np


def scipy_distances(voxels: np.ndarray, metric: str, signed: bool, cap: int) -> np.ndarray:
    """scipy's capped transform of ``voxels`` as a world of ``metric`` and ``signed`` reads it
    (``World.read_distance``): distances in voxels, float64; in a signed world the solids' are
    minus their distance to air, the world's outside counting as air."""
    from scipy.ndimage import distance_transform_cdt, distance_transform_edt

    def transform(mask: np.ndarray) -> np.ndarray:  # distance of each True to the nearest False
        if mask.all():
            return np.full(mask.shape, float(cap))
        d = distance_transform_edt(mask) if metric == "euclidean" else distance_transform_cdt(mask, metric="taxicab")
        d = np.minimum(d, cap)
        return d.astype(np.float32).astype(np.float64) if metric == "euclidean" else d.astype(np.float64)

    solid = voxels != 0
    out = transform(~solid)
    if signed and solid.any():  # the world's outside counts as air
        inside = transform(np.pad(solid, 1, constant_values=False))[1:-1, 1:-1, 1:-1]
        out[solid] = -inside[solid]
    return out


def compare(algorithm: str, n: int, field: np.ndarray, reference: np.ndarray) -> dict:
    """How far ``field`` is from ``reference``: the share of voxels equal, the largest and mean
    error, and how many voxels lie below the truth (unsafe for a ray marcher)."""
    error = field.astype(np.int32) - reference.astype(np.int32)
    return {"algorithm": algorithm, "world_size": n, "exact_share": float((error == 0).mean()),
            "max_error": int(np.abs(error).max()), "mean_error": float(np.abs(error).mean()),
            "underestimates": int((error < 0).sum())}
