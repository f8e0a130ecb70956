"""A model-based test of the log and recovery: random appends, snapshots (lagging, current and
replacing), torn tails, damage in the middle and restarts; after every restart the recovered
state must equal the model's — the latest snapshot and exactly the acknowledged records after it."""

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from sdfserver.errors import CorruptData
from sdfserver.storage import Storage
from sdfserver.storage.framing import encode_record

CONFIG = {"size": [4, 4, 4], "chunk_size": 4, "max_distance": 9, "algorithm": "exact"}


class LogMachine(RuleBasedStateMachine):
    def __init__(self):
        super().__init__()
        self.tmp = Path(tempfile.mkdtemp(prefix="sdf-log-model-"))
        self.storage = Storage(self.tmp)
        self.store = self.storage.create_world("w", {"config": CONFIG})
        self.acked: dict[int, bytes] = {}
        self.snap_version, self.snap_voxels = 0, None
        self.last = 0

    def teardown(self):
        self.store.close()
        self.storage.close()
        shutil.rmtree(self.tmp)

    def segment(self) -> Path:
        return self.store.log.segment

    @rule(payload=st.binary(max_size=64), count=st.integers(1, 4))
    def append(self, payload, count):
        futures = []
        for _ in range(count):
            self.last += 1
            futures.append((self.last, self.store.append(self.last, payload)))
        for version, future in futures:
            future.result()
            self.acked[version] = payload

    @rule(lag=st.integers(0, 5), seed=st.integers(0, 2 ** 32 - 1))
    def snapshot(self, lag, seed):
        version = max(self.snap_version, self.last - lag)
        voxels = np.random.default_rng(seed).integers(0, 256, size=(4, 4, 4), dtype=np.uint8)
        self.store.snapshot(version, CONFIG, voxels)
        self.snap_version, self.snap_voxels = version, voxels

    @rule(seed=st.integers(0, 2 ** 32 - 1))
    def replace_world(self, seed):
        voxels = np.random.default_rng(seed).integers(0, 256, size=(4, 4, 4), dtype=np.uint8)
        self.last += 1
        self.store.snapshot(self.last, CONFIG, voxels)
        self.snap_version, self.snap_voxels = self.last, voxels

    @rule(payload=st.binary(max_size=64), keep=st.floats(0, 0.999), garbage=st.booleans())
    def crash_mid_append(self, payload, keep, garbage):
        """An append that never completed: part of a frame (or junk) at the tail, then restart."""
        frame = encode_record(self.last + 1, payload)
        tail = bytes(len(frame))[: int(len(frame) * keep) + 1] if garbage else frame[: int(len(frame) * keep)]
        self.store.close()
        with open(self.segment(), "ab") as f:
            f.write(tail)
        self.restart()

    @precondition(lambda self: self.last - self.snap_version >= 3 and self.store.log.last_version
                  - int(self.segment().stem.split("-")[1]) >= 3)
    @rule(data=st.data())
    def damage_the_middle(self, data):
        """Flip one byte in a record that a valid record follows: recovery must refuse, not drop."""
        self.store.close()
        path = self.segment()
        original = path.read_bytes()
        offsets, at = [], 16
        while at < len(original):
            offsets.append(at)
            at += 16 + int.from_bytes(original[at:at + 4], "little")
        target = data.draw(st.sampled_from(offsets[:-1]))
        where = target + data.draw(st.integers(0, offsets[offsets.index(target) + 1] - target - 1))
        damaged = bytearray(original)
        damaged[where] ^= 1 << data.draw(st.integers(0, 7))
        path.write_bytes(bytes(damaged))
        self.storage.close()
        self.storage = Storage(self.tmp)
        with pytest.raises(CorruptData) as info:
            self.storage.open_world("w")
        assert str(path) in str(info.value)
        path.write_bytes(original)  # repair, and go on
        self.store, recovered = self.storage.open_world("w")
        self.check(recovered)

    @rule()
    def restart(self):
        self.store.close()
        self.storage.close()
        self.storage = Storage(self.tmp)
        self.store, recovered = self.storage.open_world("w")
        self.check(recovered)

    def check(self, recovered):
        assert recovered.snapshot_version == self.snap_version
        if self.snap_voxels is None:
            assert recovered.voxels is None
        else:
            np.testing.assert_array_equal(recovered.voxels, self.snap_voxels)
        expected = [(v, self.acked[v]) for v in sorted(self.acked) if v > self.snap_version]
        assert recovered.records == expected
        assert recovered.last_version == self.last

    @invariant()
    def versions_continue(self):
        assert self.store.last_version == self.last


LogMachine.TestCase.settings = settings(max_examples=40, stateful_step_count=25, deadline=None,
                                        suppress_health_check=[HealthCheck.too_slow])
TestLogMachine = LogMachine.TestCase
