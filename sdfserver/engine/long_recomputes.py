"""Recomputes that run in pieces across engine steps, and the commands held behind them.

A recompute that would hold the engine past its step budget (``World.begin_recompute`` with a
piece length: fim, jfa, jfa_fim or brute over many voxels) is not run to its end in one step.
Each step gives the running ones the budget, a share each, and between steps the engine serves
every other world. While a world's recompute runs, the commands that would see or change its
field (edits, reads, queries, frames, subscriptions, reconfigurations, moves) wait here in
arrival order and go back to the engine when it is done; the field's version moves only then, so
nothing reads a partial field. Deleting the world stops its recompute after the piece on the
device; stopping the engine fails what waits here with the engine's other waiting commands.

A world restored at start-up has its field computed by the engine's first step, which serves
its reads after that (or holds them here, where the recompute runs in pieces).
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Callable

from sdfserver.engine.commands import (
    ApplyEdits, CopyBricks, Draw, PickAt, Query, Read, Reconfigure, ReleaseWorld, Subscribe,
)
from sdfserver.recompute import PendingRecompute

log = logging.getLogger("sdfserver.engine")
Pending = tuple[Any, Future]
# the commands that wait for a world's running recompute (Describe and DeleteWorld do not)
HELD_TYPES = (ApplyEdits, Reconfigure, ReleaseWorld, Read, Query, Draw, PickAt, CopyBricks, Subscribe)
PROGRESS_LOG_EVERY_S = 5.0  # a running recompute says how far it is at most this often


def world_of(command: Any) -> str | None:
    """The world a held type of command is about; None for the others."""
    if not isinstance(command, HELD_TYPES):
        return None
    return command.subscription.world_id if isinstance(command, Subscribe) else command.world_id


@dataclass
class Running:
    pending: PendingRecompute
    algorithm: str
    voxels: int  # in the regions being recomputed
    started: float  # time.monotonic()
    logged: float  # when its progress was last logged


class LongRecomputes:
    def __init__(self) -> None:
        self.running: dict[str, Running] = {}
        self._restoring: set[str] = set()  # restored worlds whose field the next step computes
        self._held: dict[str, list[Pending]] = {}
        self._released: list[Pending] = []  # held commands whose world is done: the next step's first

    def __contains__(self, world_id: str) -> bool:
        return world_id in self.running

    @property
    def has_work(self) -> bool:
        """Whether the engine has a step to run without any new command."""
        return bool(self.running or self._released or self._restoring)

    def restore(self, world_id: str) -> None:
        """A restored world's field is still to be computed, by the next step."""
        self._restoring.add(world_id)

    def take_restoring(self) -> set[str]:
        taken, self._restoring = self._restoring, set()
        return taken

    def start(self, world_id: str, pending: PendingRecompute, algorithm: str) -> None:
        voxels = sum(r.volume for r in pending.regions)
        now = time.monotonic()
        self.running[world_id] = Running(pending, algorithm, voxels, now, now)
        log.info("world %s: recomputing %d voxels with %s in pieces; its commands wait, other worlds are "
                 "served between the pieces", world_id, voxels, algorithm)

    def hold(self, command: Any, future: Future) -> bool:
        """Keep the command until its world's recompute is done; False if it need not wait."""
        world_id = world_of(command)
        if world_id is None or world_id not in self.running:
            return False
        self._held.setdefault(world_id, []).append((command, future))
        return True

    def advance(self, budget_s: float, interrupted: Callable[[], bool]) -> dict[str, PendingRecompute]:
        """Run each recompute for a share of ``budget_s`` (a piece at least), each stopping after
        a piece once ``interrupted()``; the ones done."""
        done: dict[str, PendingRecompute] = {}
        if not self.running:
            return done
        share = budget_s / len(self.running)
        for world_id, entry in list(self.running.items()):
            if not entry.pending.advance(share, interrupted):
                self._log_progress(world_id, entry)
                continue
            del self.running[world_id]
            self._released += self._held.pop(world_id, [])
            done[world_id] = entry.pending
            log.info("world %s: %s recompute of %d voxels done in %.0f ms, %d pieces", world_id, entry.algorithm,
                     entry.voxels, (time.monotonic() - entry.started) * 1e3, entry.pending.pieces_run)
        return done

    def _log_progress(self, world_id: str, entry: Running) -> None:
        now = time.monotonic()
        if now - entry.logged >= PROGRESS_LOG_EVERY_S:
            entry.logged = now
            log.info("world %s: %s recompute of %d voxels running for %.0f s, %d pieces so far", world_id,
                     entry.algorithm, entry.voxels, now - entry.started, entry.pending.pieces_run)

    def cancel(self, world_id: str, why: str = "the world is deleted") -> None:
        """Stop the world's recompute (it goes away); what waited for it runs next step (and finds
        the world gone, or a new one of that id)."""
        self._restoring.discard(world_id)
        entry = self.running.pop(world_id, None)
        if entry is not None:
            entry.pending.cancel()
            log.info("world %s: its %s recompute stopped after %d pieces (%s)", world_id, entry.algorithm,
                     entry.pending.pieces_run, why)
        self._released += self._held.pop(world_id, [])

    def give_up(self) -> list[str]:
        """A step failed: stop every running recompute and let every held command go on (a
        piece that failed would fail again each step); the worlds whose field is not done."""
        stopped = list(self.running)
        for world_id in stopped:
            self.cancel(world_id, "an engine step failed; the world recomputes whole at its next edit")
        return stopped

    def take_released(self) -> list[Pending]:
        released, self._released = self._released, []
        return released

    def all_waiting(self) -> list[Pending]:
        """The engine stops: the running recomputes stop after their piece on the device, and
        this is every command held or released and not yet taken."""
        for entry in self.running.values():
            entry.pending.cancel()
        self.running.clear()
        out = self.take_released()
        for held in self._held.values():
            out += held
        self._held.clear()
        return out

    def describe(self) -> list[dict[str, Any]]:
        """The running recomputes (any thread: /readyz and /metrics ask)."""
        now = time.monotonic()
        return [{"world": world_id, "algorithm": e.algorithm, "voxels": e.voxels,
                 "running_ms": round((now - e.started) * 1e3, 1), "pieces": e.pending.pieces_run}
                for world_id, e in list(self.running.items())]
