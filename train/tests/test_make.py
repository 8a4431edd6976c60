"""`unica make --quick` end to end: the shipped Witch from her character file to a bundle
with a refiner and an evaluation, through the binary that `cargo test --release` builds (the
README's test command runs it first); then a rerun keeps every stage, and a make cut off
during its refiner continues it from its checkpoint; a make killed at random moments
and run again ends whole."""

import json
import subprocess
from pathlib import Path

from unica_train import bundle

ROOT = Path(__file__).resolve().parents[2]
BINARY = ROOT / "target" / "release" / "unica"
WITCH = ROOT / "assets" / "witch" / "source" / "Witch.gltf"


def make(out: Path, *extra: str) -> str:
    done = subprocess.run([str(BINARY), "make", str(WITCH), "--out", str(out), "--quick", "--device", "cpu", *extra],
                          cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout


def test_make_quick_writes_a_bundle_that_loads_and_continues_where_it_stopped(tmp_path):
    assert BINARY.is_file(), f"{BINARY} is missing: run `cargo build --release` (the README's test command does)"
    out = tmp_path / "made"
    log = make(out)
    for stage in ("[1/5] bake", "[2/5] geometry", "[3/5] refiner", "[4/5] distil", "[5/5] eval"):
        assert f"{stage}: done in" in log, log
    vae, unet, extra, manifest = bundle.load(out / "bundle")
    # The distil stage gave the bundle its one-pass student, which the eval ran.
    assert manifest["sampler"]["kind"] == "one_pass", manifest["sampler"]
    student, steps, cfg = bundle.live_sampler(manifest, unet, extra)
    assert student is not unet and (steps, cfg) == (1, 1.0)
    assert "one_pass" in manifest["metrics"], sorted(manifest["metrics"])
    assert manifest["avatar"] == "Witch" and "refiner" in manifest, sorted(manifest)
    # The geometry stage wrote the live settings of its config (src/make.rs QUICK_GEOMETRY)
    # and the PCA-head VAE it asked for.
    assert manifest["vae"]["decoder"] == "pca" and manifest["heading"] == "canonical", manifest["vae"]
    assert (manifest["root_motion"], manifest["grounded"], manifest["stand_speed"]) == ("decoded", True, 0.1)
    assert manifest["sampler"]["guide_idle"] is False and manifest["sampler"]["idle_brake_frames"] == 10
    assert any(name.startswith("refiner.") for name in extra), sorted(extra)[:10]
    # The refiner has its learned residual per map pixel by default (the engine loaded it for the eval).
    assert manifest["refiner"]["pixel_residuals"] == len(extra["map.pixels"]) == extra["refiner.pixel"].shape[0]
    assert (out / "eval" / "report.md").is_file()
    state = json.loads((out / "make.json").read_text())
    assert state["done"] == ["bake", "geometry", "refiner", "distil", "eval"]
    # Each stage's time, in order, in make.json and in the last line.
    assert [stage for stage, _ in state["seconds"]] == state["done"], state
    assert all(seconds > 0 for _, seconds in state["seconds"]), state
    assert "(bake " in log and ", eval " in log, log.splitlines()[-1]

    # The same command again: nothing is redone.
    log = make(out)
    assert log.count("done before, kept") == 5, log

    # A make cut off during its refiner: the refiner resumes from its last checkpoint
    # (the geometry trainer's resume is tested in test_train.py); --until stops there.
    state["done"] = ["bake", "geometry"]
    (out / "make.json").write_text(json.dumps(state))
    log = make(out, "--until", "refiner")
    assert "[2/5] geometry → geometry/ (VAE + UNet run; bundle/ from it): done before, kept" in log, log
    assert "resumed at step 10" in log and "stopped after refiner (--until)" in log, log
    assert "[4/5]" not in log and not (out / "distil").exists(), log
    _, _, extra, manifest = bundle.load(out / "bundle")
    assert "refiner" in manifest

    # The refiner's evaluation alone (--eval-only) on the made bundle: the held-out
    # frames' PSNR, SSIM and coverage (the drawn alpha inside the render's foreground).
    config = tmp_path / "eval.json"
    # As `unica make --quick` trains it (src/make.rs): 32² images, clip 2 held out.
    config.write_text(json.dumps({"image_size": 32, "eval_frames": 2, "held_out_clips": [2]}))
    done = subprocess.run(["python3", "-m", "unica_train.refiner", "--eval-only", "--bundle", str(out / "bundle"), "--data", str(out / "data"),
                           "--out", str(tmp_path / "eval_only"), "--config", str(config)], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    metrics = json.loads((tmp_path / "eval_only" / "refiner_eval.json").read_text())
    assert metrics["views"] > 0, metrics
    for name in ("base", "refined"):
        assert 0.0 < metrics[name]["coverage"] <= 1.0 and metrics[name]["psnr"] > 10, metrics


def test_make_quick_on_two_processes_plays_in_the_engine(tmp_path):
    # `--gpus 2` on the CPU: the geometry model and the refiner train data-parallel in two
    # gloo processes under torchrun, on the same samples in half the steps.
    out = tmp_path / "two"
    log = make(out, "--gpus", "2", "--until", "distil")
    assert log.count("parameters in sync across 2 processes") == 2, log
    assert "step 5/5" in log, log  # the refiner's 10 frames in 5 steps of 2
    config = json.loads((out / "geometry" / "config.json").read_text())
    assert (config["vae_steps"], config["unet_steps"], config["stage2_steps"]) == (10, 10, 5), config
    render = subprocess.run([str(BINARY), "render", "--bundle", str(out / "bundle"), "--keys", "3W", "--out",
                             str(tmp_path / "frames"), "--size", "32", "--views", "1"], cwd=ROOT, capture_output=True, text=True)
    assert render.returncode == 0, render.stderr[-3000:]
    manifest = json.loads((tmp_path / "frames" / "manifest.json").read_text())
    assert len(manifest["frames"]) == 3, manifest


def _trainers_writing_into(out: Path) -> list[str]:
    """Command lines of running processes that name `out` (trainers left behind)."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if str(out) in cmdline:
            found.append(cmdline)
    return found


def _assert_none_left_writing_into(out: Path) -> None:
    """No process names `out` within 10 s (a killed make's trainers die with it)."""
    import time

    deadline = time.time() + 10
    while _trainers_writing_into(out) and time.time() < deadline:
        time.sleep(0.1)
    assert not _trainers_writing_into(out), _trainers_writing_into(out)


def test_make_quick_killed_at_random_moments_and_run_again_ends_whole(tmp_path):
    # `unica make --quick` killed with SIGKILL (the make alone: its trainers die with it)
    # at 3 moments drawn from a fixed seed over the first 4 minutes, each time started
    # again with the same command, then run to the end: no trainer is left running after
    # a kill, and the end is a make like any other (every stage done, a bundle that loads
    # with its refiner and student, the evaluation's report), no staging folder left.
    import random
    import signal
    import time

    out = tmp_path / "made"
    rng = random.Random(51)
    command = [str(BINARY), "make", str(WITCH), "--out", str(out), "--quick", "--device", "cpu"]
    for moment in sorted(rng.uniform(5, 240) for _ in range(3)):
        started = time.time()
        run = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while run.poll() is None and time.time() - started < moment:
            time.sleep(0.05)
        if run.poll() is None:
            run.send_signal(signal.SIGKILL)
        run.wait()
        _assert_none_left_writing_into(out)
    make(out)
    state = json.loads((out / "make.json").read_text())
    assert state["done"] == ["bake", "geometry", "refiner", "distil", "eval"], state
    _, _, extra, manifest = bundle.load(out / "bundle")
    assert manifest["sampler"]["kind"] == "one_pass" and "refiner" in manifest, sorted(manifest)
    assert (out / "eval" / "report.md").is_file()
    assert not [p for p in out.rglob("*") if p.name.endswith((".tmp", ".new", ".old"))]


def test_make_on_two_processes_killed_leaves_no_trainer_running(tmp_path):
    # With --gpus 2 the make's child is torchrun, started as unica_train.torchrun so that
    # it asks to die with the make (plain torchrun outlived a killed make by more than
    # 10 s on a CI machine); its workers die with it. Nothing may be left.
    import signal
    import time

    out = tmp_path / "two"
    run = subprocess.Popen([str(BINARY), "make", str(WITCH), "--out", str(out), "--quick", "--device", "cpu", "--gpus", "2"],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    started = time.time()
    def launched():  # torchrun and its two workers
        found = _trainers_writing_into(out)
        return any("unica_train.torchrun" in c for c in found) and sum("unica_train.train" in c for c in found) >= 3

    while not launched() and time.time() - started < 180:
        time.sleep(0.2)
    assert launched(), _trainers_writing_into(out)
    time.sleep(2)
    run.send_signal(signal.SIGKILL)
    run.wait()
    _assert_none_left_writing_into(out)


def test_a_trainer_under_a_make_that_is_pid_1_runs(tmp_path):
    # A make as a container's entry point is pid 1: its children must not take their
    # parent for dead (they exited at once, silently); a child whose make is another
    # process and which was taken in by pid 1 does exit.
    import os
    import sys

    script = f"{sys.executable} -c 'import unica_train'"
    env = dict(os.environ, PYTHONPATH=str(ROOT / "train"))
    for make, code in (("1", 0), ("4242", 1)):
        done = subprocess.run(["unshare", "-fp", "--mount-proc", "sh", "-c", script], capture_output=True, text=True,
                              env=dict(env, UNICA_DIE_WITH_PARENT=make))
        assert done.returncode == code, (make, done.returncode, done.stderr[-2000:])
