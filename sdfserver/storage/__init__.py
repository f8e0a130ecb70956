"""Durable worlds: write-ahead log with group commit, snapshots, recovery, the catalog of
worlds, and import / export formats. Knows files and bytes, never the device or HTTP.

    store.py      Storage (data directory, catalog, shared committer), WorldStore (one world)
    wal.py        WorldLog (segments, append, rotate, trim), Committer (group fdatasync)
    framing.py    record framing (length, version, CRC32) and segment scanning
    recovery.py   snapshot + log -> Recovered; torn tails vs corruption
    snapshot.py   the snapshot file, also the download / upload format
    codec.py      edit batches as msgpack record payloads
    npyfile.py    .npy import / export
    voxfile.py    MagicaVoxel .vox import / export
    uploads.py    an upload's format told by its first bytes; each format's largest body
    fsutil.py     fsync of directories, atomic replacement
"""

from sdfserver.storage.codec import batch_parts, decode_batch, encode_batch
from sdfserver.storage.npyfile import dump_npy, load_npy, pad_to_chunks
from sdfserver.storage.recovery import Recovered
from sdfserver.storage.snapshot import Snapshot, decode_upload, encode_snapshot
from sdfserver.storage.store import DEFAULT_DATA_DIR, Storage, WorldStore, check_world_id
from sdfserver.storage.voxfile import dump_vox, load_vox

__all__ = [
    "DEFAULT_DATA_DIR", "Recovered", "Snapshot", "Storage", "WorldStore", "check_world_id",
    "batch_parts", "decode_batch", "decode_upload", "dump_npy", "dump_vox", "encode_batch", "encode_snapshot",
    "load_npy", "load_vox", "pad_to_chunks",
]
