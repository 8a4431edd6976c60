"""Checkpoints cannot run code (a pickle that would is refused on every resume path) and
are never seen half-written."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
import torch

from unica_train import checkpoint

PACKAGE = Path(checkpoint.__file__).parent


class RunsCode:
    """Unpickling this calls `open(marker, "w")`: a stand-in for any code a pickle can run."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def test_a_checkpoint_that_would_run_code_is_refused_with_its_name(tmp_path):
    marker = tmp_path / "ran"
    bad = tmp_path / "checkpoint.pt"
    torch.save({"model": {"w": torch.zeros(2)}, "step": 3, "payload": RunsCode(marker)}, bad)
    with pytest.raises(checkpoint.UnsafeCheckpoint) as refused:
        checkpoint.load(bad)
    message = str(refused.value)
    assert message.startswith(f"error: {bad}: ") and "\n" not in message, message
    assert not marker.exists(), "loading the checkpoint ran its code"
    # The same file through plain pickle would have run it: the test's payload is real.
    torch.load(bad, weights_only=False)
    assert marker.exists()


def test_tensors_and_plain_data_round_trip(tmp_path):
    path = tmp_path / "state.pt"
    gen = torch.Generator().manual_seed(7)
    state = {"model": {"w": torch.arange(6.0).reshape(2, 3)}, "gen": gen.get_state(), "step": 12,
             "extra": {"train": {"lr": 1e-3, "data": "x"}, "beta": 0.5, "list": [1, 2]}}
    checkpoint.save(state, path)
    loaded = checkpoint.load(path)
    assert torch.equal(loaded["model"]["w"], state["model"]["w"])
    assert torch.equal(loaded["gen"], state["gen"]) and loaded["extra"] == state["extra"]
    assert not (tmp_path / "state.pt.tmp").exists()


def test_a_save_killed_part_way_leaves_the_previous_checkpoint_whole(tmp_path):
    path = tmp_path / "state.pt"
    checkpoint.save({"step": 1}, path)
    # A run killed while writing leaves only the temporary file behind, half written.
    (tmp_path / "state.pt.tmp").write_bytes(b"\x80\x02half")
    assert checkpoint.load(path)["step"] == 1
    checkpoint.save({"step": 2}, path)
    assert checkpoint.load(path)["step"] == 2 and not (tmp_path / "state.pt.tmp").exists()


def test_a_truncated_checkpoint_is_an_error_naming_it(tmp_path):
    path = tmp_path / "state.pt"
    checkpoint.save({"step": 1, "w": torch.zeros(100)}, path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(checkpoint.UnsafeCheckpoint, match=re.escape(str(path))):
        checkpoint.load(path)


def test_every_resume_path_reads_through_checkpoint_load():
    # Every torch.load in the trainer is checkpoint.load's own; the resume paths (geometry
    # trainer, its latents cache, refiner, distillation, auto-rig trainer) call it.
    loads = {}
    for file in sorted(PACKAGE.rglob("*.py")):
        text = file.read_text()
        loads[str(file.relative_to(PACKAGE))] = len(re.findall(r"torch\.load\(", text))
        assert "weights_only=False" not in text, file
    assert {k: v for k, v in loads.items() if v} == {"checkpoint.py": 1}, loads
    for name, count in {"train.py": 2, "refiner/training.py": 1, "distil.py": 1, "rig.py": 1}.items():
        assert (PACKAGE / name).read_text().count("checkpoint_file.load(") == count, name
    # And every checkpoint is written through checkpoint.save (temporary file, renamed).
    saves = {f.name: len(re.findall(r"torch\.save\(", f.read_text())) for f in PACKAGE.rglob("*.py")}
    assert {k: v for k, v in saves.items() if v} == {"checkpoint.py": 1}, saves
    assert os.path.exists(PACKAGE / "checkpoint.py")


def test_a_folder_is_replaced_whole_and_keeps_its_other_files(tmp_path):
    d = tmp_path / "bundle"
    checkpoint.write_folder_atomic(d, {"a": b"1", "b": b"1"})
    (d / "notes.txt").write_text("kept")
    checkpoint.write_folder_atomic(d, {"a": b"2", "b": b"2"})
    assert {p.name: p.read_bytes() for p in d.iterdir()} == {"a": b"2", "b": b"2", "notes.txt": b"kept"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bundle"]  # no staging left


def test_a_folder_left_missing_between_renames_is_put_back_first(tmp_path):
    # The fallback path killed after moving the old folder aside: the next write starts
    # from it, and the stale staging copy goes.
    d = tmp_path / "bundle"
    checkpoint.write_folder_atomic(d, {"a": b"1", "keep": b"k"})
    os.rename(d, tmp_path / ".bundle.old")
    (tmp_path / ".bundle.new").mkdir()
    checkpoint.write_folder_atomic(d, {"a": b"2"})
    assert {p.name: p.read_bytes() for p in d.iterdir()} == {"a": b"2", "keep": b"k"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bundle"]


WRITER = """
import sys
from unica_train import checkpoint
d, n = sys.argv[1], 0
while True:
    n += 1
    body = str(n).encode() * 200_000
    checkpoint.write_folder_atomic(d, {"weights": body, "manifest": str(n).encode()})
"""


def _whole(d: Path) -> int:
    """The generation of a bundle folder whose two files agree; fails on a mix. Both are
    read through one handle on the folder, as a reader that must not mix generations
    reads them (a swap between two opens by path would give it one file of each)."""
    folder = os.open(d, os.O_RDONLY)
    try:
        def read(name):
            fd = os.open(name, os.O_RDONLY, dir_fd=folder)
            with os.fdopen(fd, "rb") as f:
                return f.read()
        manifest, weights = read("manifest"), read("weights")
    finally:
        os.close(folder)
    assert weights == manifest * 200_000, f"manifest {manifest!r} beside other weights"
    return int(manifest)


def _current(d: Path) -> int | None:
    """`_whole`, or None where the folder read was swapped out and removed meanwhile
    (a reader then reads again)."""
    try:
        return _whole(d)
    except FileNotFoundError:
        return None


def test_a_bundle_read_while_written_and_killed_is_always_one_whole_generation(tmp_path):
    # A writer replaces the folder over and over (2 files that must agree) while this
    # process reads it; the writer is killed with SIGKILL at 5 random moments and started
    # again. Every read sees one generation whole (or, where the folder it holds was
    # swapped out and removed meanwhile, no file), and after each kill so does the folder.
    # Written in place instead, the same test fails at once (tried).
    import random
    import signal
    import subprocess
    import sys
    import time

    d = tmp_path / "bundle"
    checkpoint.write_folder_atomic(d, {"weights": b"0" * 200_000, "manifest": b"0"})
    rng = random.Random(5)
    reads, generations = 0, set()
    for _ in range(5):
        writer = subprocess.Popen([sys.executable, "-c", WRITER, str(d)])
        before = _whole(d)
        while _current(d) in (before, None):  # the writer has started (it imports torch)
            assert writer.poll() is None, "the writer died"
        deadline = time.time() + rng.uniform(0.3, 1.5)
        while time.time() < deadline:
            generation = _current(d)
            if generation is not None:
                generations.add(generation)
                reads += 1
        writer.send_signal(signal.SIGKILL)
        writer.wait()
        _whole(d)
    assert reads > 100 and len(generations) > 10, (reads, len(generations))


def test_every_file_the_trainer_writes_goes_through_a_synced_rename():
    # Results, reports, figures, logs' rewrites and tensors: no write in the package but
    # checkpoint.py's own (write_file_atomic, write_text, write_tensors, save) and the
    # appends of a log a row at a time (cut back by `cut_log` when a run resumes).
    direct = re.compile(r"\.write_text\(|\.write_bytes\(|save_file\(|savefig\((?!buffer)|imsave\((?!buffer)|"
                        r"open\([^)]*[\"'](w|wb|x|r\+)[\"']")
    found = {}
    for file in sorted(PACKAGE.rglob("*.py")):
        hits = [line.strip() for line in file.read_text().splitlines()
                if direct.search(line.replace("checkpoint_file.write_text(", "").replace("write_file_atomic(", ""))]
        if hits:
            found[str(file.relative_to(PACKAGE))] = hits
    assert list(found) == ["checkpoint.py"], found
    assert len(found["checkpoint.py"]) == 2, found  # write_file_atomic's and write_folder_atomic's opens


def test_a_resumed_log_keeps_the_steps_up_to_its_checkpoint_and_drops_a_cut_row(tmp_path):
    log = tmp_path / "losses.csv"
    log.write_text("step,loss\r\n1,0.5\r\n2,0.4\r\n3,0.3\r\n4,0.2\r\n5,0.")  # killed while writing step 5
    checkpoint.cut_log(log, 3)
    assert log.read_bytes() == b"step,loss\r\n1,0.5\r\n2,0.4\r\n3,0.3\r\n"
    # Per stage: only the resumed stage's rows past its step go (the step in column 1).
    log.write_text("stage,step,name,value\nvae,50,loss,1\nvae,100,loss,0.5\nunet1,50,loss,2\nunet1,100,loss,1\n")
    checkpoint.cut_log(log, 50, step_column=1, only=lambda row: row[0].startswith("unet"))
    assert log.read_text() == "stage,step,name,value\nvae,50,loss,1\nvae,100,loss,0.5\nunet1,50,loss,2\n"
    checkpoint.cut_log(tmp_path / "absent.csv", 3)
    assert not (tmp_path / "absent.csv").exists()
