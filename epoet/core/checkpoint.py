"""Atomic save/load of a run's whole state, so a killed run resumes where it stopped.

One format for every algorithm: a header (magic, format version, payload length, CRC-32) followed
by a pickle (protocol 5) of a dict of numpy arrays, plain Python objects and torch state dicts
(torch tensors pickle natively). The CRC catches bit rot and truncation that pickle alone would
load silently (a damaged float array still unpickles). Pickle runs code on load: only load
checkpoints this project wrote.

Layout: a run folder (Hydra's job output directory) holds its checkpoint as `checkpoint.pkl`;
`find_checkpoint` accepts either the folder or the file. A checkpoint written before a rename
loads as today's (`RENAMED_MODULES`, `RENAMED_KEYS`), so old runs resume and are recorded.
"""

from __future__ import annotations

import os
import pickle
import struct
import zlib
from pathlib import Path
from typing import Any

from epoet.core.files import atomic_write

CHECKPOINT_NAME = "checkpoint.pkl"
# 2: ePOET-SAC's joins, 'learner' for the RL state, compact replay, elapsed time
FORMAT_VERSION = 2
_MAGIC = b"EPOETCKP"
# magic, format version (uint32), payload length (uint64), CRC-32 of the payload (uint32)
_HEADER = struct.Struct("<8sIQI")
_CHUNK = 1 << 24  # 16 MiB reads when verifying the CRC: bounded memory for large replay buffers
# Names older checkpoints hold that have since changed, mapped on load (the format is the same,
# so no version bump): the packages of the classes they pickled (ePOET's package was
# epoet/poet/ before issue 47) and the runners' top-level keys (ePOET's loop state was "poet").
RENAMED_MODULES = {"epoet.poet": "epoet.open_ended"}
RENAMED_KEYS = {"poet": "open_ended"}


class CheckpointError(ValueError):
    """A checkpoint that cannot be written or read; the message is one sentence naming the path."""


class _RenamingUnpickler(pickle.Unpickler):
    """Finds a class an older checkpoint pickled under a module path since renamed."""

    def find_class(self, module: str, name: str) -> Any:
        for old, new in RENAMED_MODULES.items():
            if module == old or module.startswith(f"{old}."):
                module = new + module[len(old) :]
        return super().find_class(module, name)


class _CrcWriter:
    """File wrapper that counts bytes and updates a CRC as pickle streams into it.

    Streaming avoids holding a second in-memory copy of a large state (e.g. a SAC replay buffer).
    """

    def __init__(self, file: Any) -> None:
        self._file = file
        self.crc = 0
        self.length = 0

    def write(self, data: bytes | memoryview) -> int:
        self.crc = zlib.crc32(data, self.crc)
        self.length += memoryview(data).nbytes
        return self._file.write(data)


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> None:
    """Write `state` to `path` atomically (`atomic_write`): on any failure the previous
    checkpoint is untouched."""
    path = Path(path)
    if not isinstance(state, dict):
        raise CheckpointError(
            f"cannot save checkpoint {path}: state must be a dict, got {type(state).__name__}."
        )
    if path.is_dir():
        raise CheckpointError(f"cannot save checkpoint {path}: it is a directory.")
    try:
        with atomic_write(path) as file:
            file.write(_HEADER.pack(_MAGIC, FORMAT_VERSION, 0, 0))  # length and CRC patched below
            writer = _CrcWriter(file)
            pickle.dump(state, writer, protocol=5)
            file.seek(0)
            file.write(_HEADER.pack(_MAGIC, FORMAT_VERSION, writer.length, writer.crc))
    except Exception as exc:  # KeyboardInterrupt / SystemExit pass through unchanged
        raise CheckpointError(
            f"cannot save checkpoint {path}: {type(exc).__name__}: {exc}."
        ) from exc


def find_checkpoint(path: str | Path) -> Path:
    """Resolve a run folder or a checkpoint file to the checkpoint file."""
    path = Path(path)
    if path.is_dir():
        candidate = path / CHECKPOINT_NAME
        if not candidate.is_file():
            raise CheckpointError(
                f"no checkpoint in run folder {path}: {CHECKPOINT_NAME} does not exist."
            )
        return candidate
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist.")
    return path


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint written by `save_checkpoint` (given the file or its run folder)."""
    file_path = find_checkpoint(path)
    try:
        with open(file_path, "rb") as file:
            header = file.read(_HEADER.size)
            if len(header) < _HEADER.size:
                raise CheckpointError(
                    f"checkpoint {file_path} is truncated: "
                    f"{len(header)} bytes, shorter than its header."
                )
            magic, version, length, crc = _HEADER.unpack(header)
            if magic != _MAGIC:
                raise CheckpointError(f"{file_path} is not an epoet checkpoint (wrong magic).")
            if version != FORMAT_VERSION:
                raise CheckpointError(
                    f"checkpoint {file_path} has format version {version}, "
                    f"this code reads version {FORMAT_VERSION}."
                )
            size = os.fstat(file.fileno()).st_size - _HEADER.size
            if size != length:
                raise CheckpointError(
                    f"checkpoint {file_path} is truncated or padded: "
                    f"payload is {size} bytes, header says {length}."
                )
            actual = 0
            while chunk := file.read(_CHUNK):
                actual = zlib.crc32(chunk, actual)
            if actual != crc:
                raise CheckpointError(f"checkpoint {file_path} is corrupt: CRC mismatch.")
            file.seek(_HEADER.size)
            state = _RenamingUnpickler(file).load()
    except OSError as exc:
        raise CheckpointError(f"cannot read checkpoint {file_path}: {exc.strerror}.") from exc
    except CheckpointError:
        raise
    except Exception as exc:  # the CRC matched, so this is a class that no longer unpickles
        raise CheckpointError(
            f"cannot unpickle checkpoint {file_path}: {type(exc).__name__}: {exc}."
        ) from exc
    if not isinstance(state, dict):
        raise CheckpointError(f"checkpoint {file_path} does not hold a dict.")
    return {RENAMED_KEYS.get(key) or key: value for key, value in state.items()}
