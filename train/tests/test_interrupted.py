"""Every trainer killed with SIGKILL at several points of its run, then started again
with `--resume`, ends with what an uninterrupted run writes: outputs that load, the same
metrics' keys, each step logged once, no temporary left (issue #51). The points are drawn
from a fixed seed across an uninterrupted run's time. The geometry trainer, the refiner,
the distillation and the auto-rig trainer; `unica make` is killed in test_make.py."""

import csv
import json
import random
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_train import TINY
from unica_train import bundle

ROOT = Path(__file__).resolve().parents[2]
BINARY = ROOT / "target" / "release" / "unica"
WITCH = ROOT / "assets" / "witch" / "source" / "Witch.gltf"

# test_train's tiny model with enough steps (checkpoints every 5) that a kill can land in
# each stage.
SMALL = {**TINY, "vae_steps": 20, "unet_steps": 20, "stage2_steps": 5, "checkpoint_every": 5}


def module(name, *args):
    return [sys.executable, "-m", f"unica_train.{name}", *map(str, args)]


def killed_and_resumed(tmp_path, command, check, resumed, checkpoints, kills=3, seed=51):
    """Runs `command(out, resume)` once to the end into tmp_path/reference; then `kills`
    times into a fresh folder, killed and run again with resume to the end;
    `check(out, reference)` after each, and no temporary or staging file may be left. The
    first kills come after a share of the reference's time drawn uniformly from
    [0.1, 0.9]; the last as soon as one of `checkpoints` (paths in the run's folder) exists,
    and its rerun must say `resumed` (it continued from that checkpoint). Timed kills
    alone all came before the first checkpoint on a loaded machine, where start-up (the
    distillation's teacher samples) took longer than in the reference run."""
    reference = tmp_path / "reference"
    started = time.time()
    subprocess.run(command(reference, False), check=True, capture_output=True)
    took = time.time() - started
    check(reference, reference)
    rng = random.Random(seed)
    for k in range(kills):
        out = tmp_path / f"killed{k}"
        last = k == kills - 1
        after = took * rng.uniform(0.1, 0.9)
        child = subprocess.Popen(command(out, False), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if last:
            deadline = time.time() + 20 * took + 60
            def saved():
                return any((out / name).exists() for name in checkpoints)

            while not saved() and child.poll() is None and time.time() < deadline:
                time.sleep(0.02)
            assert saved(), f"none of {checkpoints} in {out} before the run ended"
            when = "once its checkpoint existed"
        else:
            try:
                child.wait(timeout=after)
            except subprocess.TimeoutExpired:
                pass
            when = f"after {after:.1f} s of {took:.1f}"
        child.kill()
        finished = child.wait() == 0
        rerun = subprocess.run(command(out, True), capture_output=True, text=True)
        assert rerun.returncode == 0, f"killed {when}: {rerun.stderr[-2000:]}"
        left = [p for p in out.parent.rglob("*") if p.name.endswith((".tmp", ".new", ".old"))]
        assert not left, f"killed {when}: {left} left"
        check(out, reference)
        if last and not finished:
            assert resumed in rerun.stdout + rerun.stderr, f"killed {when}, the rerun did not say {resumed!r}"


def logged_steps(path, column="step"):
    with open(path, newline="") as f:
        return [int(row[column]) for row in csv.DictReader(f)]


def test_the_trainer_killed_part_way_resumes_to_a_bundle_that_loads(quick_dataset_dir, tmp_path):
    config = tmp_path / "small.json"
    config.write_text(json.dumps(SMALL))

    def command(out, resume):
        return module("train", "--data", quick_dataset_dir, "--out", out, "--config", config) + (["--resume"] if resume else [])

    def check(out, reference):
        vae, unet, extra, manifest = bundle.load(out / "bundle")
        assert manifest["pca"]["components"] == 8
        assert json.loads((out / "metrics.json").read_text()).keys() == json.loads((reference / "metrics.json").read_text()).keys()
        with open(out / "losses.csv", newline="") as f:
            rows = [(r["stage"], int(r["step"]), r["name"]) for r in csv.DictReader(f)]
        assert len(rows) == len(set(rows)), "a step logged twice"

    killed_and_resumed(tmp_path, command, check, "resumed", ["checkpoints/vae.pt", "checkpoints/unet.pt"])


@pytest.fixture(scope="module")
def baked_with_geometry(tmp_path_factory):
    """`unica bake --quick` of the Witch (renders included) and a tiny geometry bundle
    trained on it: what the refiner trains on."""
    assert BINARY.is_file(), f"{BINARY} is missing: run `cargo build --release` (the README's test command does)"
    tmp = tmp_path_factory.mktemp("baked")
    subprocess.run([str(BINARY), "bake", str(WITCH), "--quick", "--out", str(tmp / "data")], check=True, capture_output=True)
    config = tmp / "tiny.json"
    config.write_text(json.dumps(dict(TINY, unet_steps=2, stage2_steps=0)))
    subprocess.run(module("train", "--data", tmp / "data", "--out", tmp / "geometry", "--config", config), check=True, capture_output=True)
    return tmp / "data", tmp / "geometry" / "bundle"


def test_the_refiner_killed_part_way_resumes_and_writes_its_bundle(baked_with_geometry, tmp_path):
    data, geometry = baked_with_geometry
    config = tmp_path / "refiner.json"
    # `unica make --quick`'s refiner (src/make.rs), 40 steps, checkpointed every 5.
    config.write_text(json.dumps({
        "model": {"channels": [8, 16], "depths": [1, 1], "heads": [2, 2], "decoder_depth": 1, "patch": 16, "stride": 4},
        "steps": 40, "image_size": 32, "held_out_clips": [2], "eval_frames": 2, "checkpoint_every": 5}))

    def command(out, resume):
        target = out.with_name(out.name + "-bundle")  # the bundle this run writes its refiner into
        if not resume:
            shutil.copytree(geometry, target)
        return module("refiner", "--bundle", target, "--data", data, "--out", out, "--config", config, "--device", "cpu",
                      "--write-bundle") + (["--resume"] if resume else [])

    def check(out, reference):
        metrics = json.loads((out / "refiner_eval.json").read_text())
        assert metrics.keys() == json.loads((reference / "refiner_eval.json").read_text()).keys()
        _, _, extra, manifest = bundle.load(out.with_name(out.name + "-bundle"))
        assert "refiner" in manifest and any(k.startswith("refiner.") for k in extra)
        with open(out / "refiner_losses.csv", newline="") as f:
            assert [int(row[0]) for row in csv.reader(f)] == list(range(40)), "each step logged once"

    killed_and_resumed(tmp_path, command, check, "resumed at step", ["refiner_checkpoint.pt"])


def test_the_distillation_killed_part_way_resumes_to_a_one_pass_bundle(quick_dataset_dir, tmp_path):
    from test_train import trained_bundle_with_refiner

    (tmp_path / "teacher").mkdir()
    first, _ = trained_bundle_with_refiner(quick_dataset_dir, tmp_path / "teacher")
    quick = ["--held-out-clips", "2", "--frames", "16", "--held-out-frames", "8", "--batch", "4", "--checkpoint-every", "2"]

    def command(out, resume):
        return module("distil", "--bundle", first / "bundle", "--data", quick_dataset_dir, "--out", out, "--steps", 40, *quick) + (
            ["--resume"] if resume else [])

    def check(out, reference):
        assert json.loads((out / "metrics.json").read_text()).keys() == json.loads((reference / "metrics.json").read_text()).keys()
        _, _, _, manifest = bundle.load(out / "bundle")
        assert manifest["sampler"]["kind"] == "one_pass"
        assert logged_steps(out / "losses.csv") == [10, 20, 30, 40], "each step logged once"

    killed_and_resumed(tmp_path, command, check, "resumed at step", ["checkpoint.pt"])


def test_the_auto_rig_trainer_killed_part_way_resumes_to_a_model_that_loads(tmp_path):
    from test_rig import TINY_SKIN, write_dataset
    from unica_train import rig

    data = write_dataset(tmp_path / "rigdata")

    def command(out, resume):
        return module("rig", "--data", data.root, "--out", out, "--model", "skin", "--steps", 1000, "--batch", 4, "--holdout", 2,
                      "--checkpoint-every", 100, "--arch", json.dumps(TINY_SKIN)) + (["--resume"] if resume else [])

    def check(out, reference):
        rig.load(out, "skin")
        assert json.loads((out / "skin_eval.json").read_text()).keys() == json.loads((reference / "skin_eval.json").read_text()).keys()
        assert logged_steps(out / "skin_losses.csv") == list(range(1, 1001)), "each step logged once"
        assert (out / "skin_curve.png").stat().st_size > 0

    killed_and_resumed(tmp_path, command, check, "resuming at step", ["skin_checkpoint.pt"])
