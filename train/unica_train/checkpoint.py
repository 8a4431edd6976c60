"""Checkpoints that cannot run code and cannot be seen half-written.

Every trainer's resume path reads its checkpoint with `load`: `torch.load` with
`weights_only=True`, which unpickles tensors and plain data (dicts, lists, numbers,
strings) and refuses any other object, so a checkpoint that was sent to the user cannot
run code when they resume from it (a pickle can name any callable to call on load). A
refused file ends the run with a one-line error naming it. `save` writes to a temporary
name beside the target, syncs it and renames it over the target, so a run killed while
saving leaves the previous checkpoint whole."""

from __future__ import annotations

import io
import os
from pathlib import Path

import torch


class UnsafeCheckpoint(SystemExit):
    """A checkpoint that holds more than tensors and plain data (or is no checkpoint)."""


def load(path: str | os.PathLike, map_location=None):
    """The tensors and plain data saved at `path`; `UnsafeCheckpoint` (a one-line
    `error: PATH: …` exit) for a file holding anything else or unreadable as one."""
    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:  # torch raises UnpicklingError, RuntimeError, EOFError, …
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise UnsafeCheckpoint(
            f"error: {path}: not loaded: a checkpoint may hold only tensors and plain data "
            f"(refused: {first[:200]}); delete it to start over"
        ) from None


def save(state, path: str | os.PathLike) -> None:
    """Writes `state` to `path` through a synced temporary file renamed over it."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    write_file_atomic(Path(path), buffer.getvalue())


def write_file_atomic(path: Path, data: bytes) -> None:
    """Writes `data` to a synced temporary file beside `path` and renames it over `path`,
    so a reader sees the old file or the new one, never half of one (every file the
    trainers write that a rerun or the engine reads: checkpoints, bundles)."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
