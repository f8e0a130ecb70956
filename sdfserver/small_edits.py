"""The shorter ways a dense world recomputes edits to small boxes (``algorithms/lower.py``), as a
part of ``World``: lowering the field around added solids, and transforming only the box where
the field can rise around erased ones (a Euclidean world: its last stage only)."""

from __future__ import annotations

from sdfserver.algorithms import AlgorithmRun
from sdfserver.algorithms.lower import lower, lowering_boxes, raise_bounds
from sdfserver.geometry import Box


class SmallEdits:
    """Mixed into ``World``, whose config, dirty set, device buffers and region launches it uses."""

    def _lowering_boxes(self, regions: list[Box] | None = None) -> list[Box] | None:
        """The edited boxes, where their recompute is ``_lower`` (``algorithms/lower.py``: an
        unsigned exact world, small boxes in large regions, a Euclidean one only where nothing
        was erased); else None. ``regions``: the dirty regions, where the caller has them."""
        cfg, dirty = self.config, self.dirty
        if dirty.all or (dirty.erased and cfg.euclidean) or cfg.algorithm != "exact" or cfg.signed \
                or cfg.focus is not None or cfg.borders != "exact":
            return None
        return lowering_boxes(dirty.boxes, self.dirty_regions() if regions is None else regions, cfg.euclidean,
                              dirty.erased)

    def _rising_regions(self, regions: list[Box], runs: list) -> list[Box]:
        """A Euclidean world's regions for its last stage: where its batches only erased, the box
        where the field can rise (``raise_bounds``), snapped to chunks, or none; else ``regions``."""
        cfg, dirty = self.config, self.dirty
        boxes = None if dirty.all or dirty.added or cfg.signed else lowering_boxes(dirty.boxes, regions, True)
        if boxes is None:
            return regions
        rising = self._rising_region(boxes, runs, euclidean=True)
        return [] if rising is None else [rising]

    def _lower(self, boxes: list[Box]) -> list[tuple[str, AlgorithmRun]]:
        """Where solids were erased, the transform of the box whose voxels may rise; then the
        field lowered around what was added."""
        cap, runs = self.config.max_distance, []
        if self.dirty.erased:
            rising = self._rising_region(boxes, runs)
            if rising is not None:
                runs += [(name, launch()) for name, launch in self._launches([rising])]
        if self.dirty.added:
            runs.append(("exact", lower(self.gpu, self.buffers, boxes, cap, self.config.euclidean)))
        return runs

    def _rising_region(self, boxes: list[Box], runs: list, euclidean: bool = False) -> Box | None:
        """The box where erasing in ``boxes`` can raise the field (``raise_bounds``, its launches
        counted in ``runs``), snapped to chunks as every region the transform is given; None
        where nothing can rise."""
        bounding = AlgorithmRun()
        runs.append(("exact", bounding))
        rising = raise_bounds(self.gpu, self.buffers, boxes, self.config.max_distance, bounding, euclidean=euclidean)
        return None if rising is None else rising.snap(self.config.chunk_size).intersect(self.world_box)
