"""Checkpoints that cannot run code and cannot be seen half-written.

Every trainer's resume path reads its checkpoint with `load`: `torch.load` with
`weights_only=True`, which unpickles tensors and plain data (dicts, lists, numbers,
strings) and refuses any other object, so a checkpoint that was sent to the user cannot
run code when they resume from it (a pickle can name any callable to call on load). A
refused file ends the run with a one-line error naming it. `save` writes to a temporary
name beside the target, syncs it and renames it over the target, so a run killed while
saving leaves the previous checkpoint whole."""

from __future__ import annotations

import csv
import ctypes
import io
import os
import shutil
from pathlib import Path
from typing import Callable

import torch
from safetensors.torch import save as safetensors_bytes


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


def write_text(path: str | os.PathLike, text: str) -> None:
    """`text` written whole or not at all (`write_file_atomic`): every JSON, CSV and
    report a trainer writes goes through here or `write_tensors`."""
    write_file_atomic(Path(path), text.encode())


def write_tensors(path: str | os.PathLike, tensors: dict, metadata: dict | None = None) -> None:
    """A safetensors file written whole or not at all."""
    tensors = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    write_file_atomic(Path(path), safetensors_bytes(tensors, metadata))


def cut_log(path: str | os.PathLike, last_step: int, step_column: int = 0,
            only: Callable[[list[str]], bool] = lambda row: True) -> None:
    """A CSV log that a run appends a row at a time, as a resumed run continues it: the
    rows `only` selects are kept up to `last_step` (the resumed checkpoint's step), so
    steps redone after a kill are not logged twice; the header and other rows are kept,
    and a row cut off by the kill (no line end) is dropped. Rewritten whole."""
    path = Path(path)
    if not path.exists():
        return
    complete = path.read_bytes().decode().split("\n")[:-1]  # line ends as written
    kept = []
    for line, row in zip(complete, csv.reader(complete)):
        step = row[step_column] if len(row) > step_column else ""
        if not step.lstrip("-").isdigit() or not only(row) or int(step) <= last_step:
            kept.append(line)
    write_text(path, "".join(line + "\n" for line in kept))


def _sync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _exchange(a: Path, b: Path) -> bool:
    """Swaps the folders `a` and `b` in one step (Linux renameat2 RENAME_EXCHANGE);
    False where the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    errno = ctypes.get_errno()
    if errno in (22, 38, 95):  # EINVAL, ENOSYS, EOPNOTSUPP: not on this file system
        return False
    raise OSError(errno, os.strerror(errno), str(b))


def write_folder_atomic(directory: str | os.PathLike, files: dict[str, bytes]) -> None:
    """Replaces the folder `directory` whole: a copy of it (its other files hard-linked)
    with `files` written and synced is made beside it, then swapped with it in one step
    (renameat2 RENAME_EXCHANGE), so a reader and a run killed at any moment see the old
    folder or the new one, never a mix of their files (a bundle's weights and manifest
    must agree). Where the system cannot swap, two renames with the old folder kept as
    `.NAME.old` until the new one is in place; a later call puts a folder left missing
    back first."""
    d = Path(directory)
    staging = d.with_name(f".{d.name}.new")
    old = d.with_name(f".{d.name}.old")
    if not d.exists() and old.exists():
        os.rename(old, d)  # a run killed between the two renames
    for leftover in (staging, old):
        if leftover.exists():
            shutil.rmtree(leftover)
    if d.exists():
        top = os.fspath(d)
        shutil.copytree(d, staging, copy_function=os.link,
                        ignore=lambda folder, names: [n for n in names if n in files] if folder == top else [])
    else:
        staging.mkdir(parents=True)
    for name, data in files.items():
        with open(staging / name, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    _sync_dir(staging)
    if not d.exists():
        os.rename(staging, d)
    elif _exchange(staging, d):
        shutil.rmtree(staging)  # the old folder, swapped out
    else:
        os.rename(d, old)
        os.rename(staging, d)
        shutil.rmtree(old)
    _sync_dir(d.parent)
