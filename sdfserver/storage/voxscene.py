"""A MagicaVoxel scene: where each model of a ``.vox`` file stands (ephtracy/voxel-model's
``MagicaVoxel-file-format-vox-extension.txt``).

The scene graph is nodes by id: ``nTRN`` (a transform: its child, and a frame dictionary with
``_t`` "x y z" translation and ``_r`` a packed rotation), ``nGRP`` (children) and ``nSHP`` (models
by index). A dictionary is int32 pairs, then each key and value as int32 length + bytes. Node 0
is the root. ``_r``'s bits: 0–1 the column of row 0's non-zero entry, 2–3 row 1's (row 2 takes the
column left), 4, 5, 6 the signs of rows 0, 1, 2 (set: −1).

Placement: a model's voxel ``v`` stands at ``R (v - floor(size / 2)) + t``, composed down the
graph (a parent's transform applied after its child's): the translation names where the model's
centre voxel goes. Nodes with ``_hidden`` "1" are left out; animation frames past the first are
ignored.
"""

from __future__ import annotations

import struct

import numpy as np

from sdfserver.errors import InvalidInput

MAX_DEPTH = 64  # a scene graph deeper than this is refused (a cycle, or a hostile file)
Placement = tuple[int, np.ndarray, np.ndarray]  # (model index, R 3x3 int, t 3 int)


class Reader:
    def __init__(self, content: bytes, what: str):
        self.data, self.at, self.what = content, 0, what

    def int32(self) -> int:
        if self.at + 4 > len(self.data):
            raise InvalidInput(f".vox: {self.what} chunk is truncated")
        (value,) = struct.unpack_from("<i", self.data, self.at)
        self.at += 4
        return value

    def string(self) -> str:
        n = self.int32()
        if n < 0 or self.at + n > len(self.data):
            raise InvalidInput(f".vox: {self.what} chunk holds a string past its end")
        value = self.data[self.at:self.at + n].decode("utf-8", "replace")
        self.at += n
        return value

    def dictionary(self) -> dict[str, str]:
        pairs = self.int32()
        if pairs < 0 or pairs > len(self.data):
            raise InvalidInput(f".vox: {self.what} chunk declares {pairs} dictionary entries")
        return {self.string(): self.string() for _ in range(pairs)}

    def count(self) -> int:
        n = self.int32()
        if n < 0 or 4 * n > len(self.data) - self.at:
            raise InvalidInput(f".vox: {self.what} chunk declares {n} entries")
        return n


class SceneGraph:
    def __init__(self) -> None:
        self.nodes: dict[int, tuple[str, object]] = {}

    def add(self, cid: bytes, content: bytes) -> None:
        what = cid.decode("ascii", "replace")
        r = Reader(content, what)
        node, attributes = r.int32(), r.dictionary()
        hidden = attributes.get("_hidden") == "1"
        if cid == b"nTRN":
            child, _reserved, _layer, frames = r.int32(), r.int32(), r.int32(), r.count()
            frame = r.dictionary() if frames else {}
            self.nodes[node] = ("transform", (child, hidden, *transform_of(frame)))
        elif cid == b"nGRP":
            self.nodes[node] = ("group", (hidden, [r.int32() for _ in range(r.count())]))
        else:  # nSHP
            models = []
            for _ in range(r.count()):
                models.append(r.int32())
                r.dictionary()
            self.nodes[node] = ("shape", (hidden, models))

    def placements(self, models: int) -> list[Placement]:
        """Every visible model instance, in the graph's order; none without a graph."""
        if not self.nodes:
            return []
        out: list[Placement] = []
        self._walk(0, np.eye(3, dtype=np.int64), np.zeros(3, dtype=np.int64), 0, out, models)
        return out

    def _walk(self, node: int, rotation: np.ndarray, translation: np.ndarray, depth: int,
              out: list[Placement], models: int) -> None:
        if depth > MAX_DEPTH:
            raise InvalidInput(f".vox: the scene graph is deeper than {MAX_DEPTH} (or has a cycle)")
        if node not in self.nodes:
            raise InvalidInput(f".vox: the scene graph names node {node}, which the file does not hold")
        kind, value = self.nodes[node]
        if kind == "transform":
            child, hidden, r, t = value
            if not hidden:  # this node's transform comes after its children's
                self._walk(child, rotation @ r, rotation @ t + translation, depth + 1, out, models)
        elif kind == "group":
            hidden, children = value
            for child in ([] if hidden else children):
                self._walk(child, rotation, translation, depth + 1, out, models)
        else:
            hidden, shapes = value
            for model in ([] if hidden else shapes):
                if not 0 <= model < models:
                    raise InvalidInput(f".vox: a shape names model {model}; the file has {models}")
                out.append((model, rotation, translation))


def transform_of(frame: dict[str, str]) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a transform node's frame dictionary."""
    try:
        t = np.array([int(v) for v in frame.get("_t", "0 0 0").split()], dtype=np.int64)
        bits = int(frame.get("_r", "4"))
    except ValueError:
        raise InvalidInput(f".vox: a transform's frame is not numbers: {frame}") from None
    if t.shape != (3,) or np.abs(t).max() > 1 << 20:
        raise InvalidInput(f".vox: a transform's translation {frame.get('_t')!r} is not three numbers in range")
    first, second = bits & 3, (bits >> 2) & 3
    if first > 2 or second > 2 or first == second:
        raise InvalidInput(f".vox: rotation {bits} is not a valid packed rotation")
    columns = [first, second, 3 - first - second]
    rotation = np.zeros((3, 3), dtype=np.int64)
    for row, column in enumerate(columns):
        rotation[row, column] = -1 if bits >> (4 + row) & 1 else 1
    return rotation, t


def place(models: list[tuple[tuple[int, int, int], np.ndarray]], placements: list[Placement]
          ) -> tuple[np.ndarray, np.ndarray]:
    """(every placed solid voxel's scene coordinates (N, 3), its colour index (N,)); later
    instances over earlier ones where they overlap."""
    coords, colours = [], []
    for model, rotation, translation in placements:  # one loop over instances
        size, xyzi = models[model]
        solid = xyzi[xyzi[:, 3] != 0]
        local = solid[:, :3].astype(np.int64) - np.array(size, dtype=np.int64) // 2
        coords.append(local @ rotation.T + translation)
        colours.append(solid[:, 3])
    if not coords:
        raise InvalidInput(".vox: the scene shows no voxel")
    return np.concatenate(coords), np.concatenate(colours)
