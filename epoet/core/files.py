"""Atomic file writes: a reader (or a resumed run) sees the old file or the new, never half of one."""

from __future__ import annotations

import io
import os
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np


@contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file to write `path` through.

    The data goes to a temporary file in the same directory (same filesystem, so `os.replace` is
    atomic), is fsynced, then renamed over `path`, and the directory is fsynced so the rename
    itself survives a crash. On any failure the temporary file is removed and `path` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    tmp = Path(tmp_name)
    try:
        os.fchmod(fd, 0o644)  # mkstemp makes 0600; outputs are as readable as any other file
        with os.fdopen(fd, "wb") as file:
            yield file
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def savez(file: BinaryIO, arrays: Mapping[str, Any]) -> None:
    """np.savez_compressed of named arrays; numpy's type hints read `**arrays` as possibly
    filling its `allow_pickle` flag, so the names go through one typed call here."""
    np.savez_compressed(file, **dict(arrays))


_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed, so the same arrays are the same bytes every time


def npz_bytes(arrays: Mapping[str, np.ndarray | np.generic]) -> bytes:
    """An .npz (np.load reads it) without the write time numpy's savez puts in it."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, value in arrays.items():
            array = io.BytesIO()
            np.lib.format.write_array(array, np.asanyarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", _ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, array.getvalue())
    return buffer.getvalue()
