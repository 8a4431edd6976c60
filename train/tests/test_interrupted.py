"""The geometry trainer killed with SIGKILL at several points of its run, then started
again with `--resume`, ends with a bundle that loads and its metrics (issue #51). The
points are drawn from a fixed seed across an uninterrupted run's time."""

import json
import random
import subprocess
import sys
import time

from test_train import TINY
from unica_train import bundle

# test_train's tiny model with enough steps (checkpoints every 5) that a kill can land in
# each stage.
SMALL = {**TINY, "vae_steps": 20, "unet_steps": 20, "stage2_steps": 5, "checkpoint_every": 5}


def command(data, out, config, resume=False):
    args = [sys.executable, "-m", "unica_train.train", "--data", str(data), "--out", str(out), "--config", str(config)]
    return args + (["--resume"] if resume else [])


def test_the_trainer_killed_part_way_resumes_to_a_bundle_that_loads(quick_dataset_dir, tmp_path):
    config = tmp_path / "small.json"
    config.write_text(json.dumps(SMALL))
    started = time.time()
    subprocess.run(command(quick_dataset_dir, tmp_path / "reference", config), check=True, capture_output=True)
    took = time.time() - started
    expected = json.loads((tmp_path / "reference" / "metrics.json").read_text()).keys()
    rng = random.Random(51)
    for k in range(3):
        out = tmp_path / f"killed{k}"
        after = took * rng.uniform(0.1, 0.9)
        child = subprocess.Popen(command(quick_dataset_dir, out, config), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            child.wait(timeout=after)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
        rerun = subprocess.run(command(quick_dataset_dir, out, config, resume=True), capture_output=True, text=True)
        assert rerun.returncode == 0, f"killed after {after:.1f} s of {took:.1f}: {rerun.stderr[-2000:]}"
        assert not list(out.rglob("*.tmp")), f"killed after {after:.1f} s: a temporary was left"
        vae, unet, extra, manifest = bundle.load(out / "bundle")
        assert manifest["pca"]["components"] == 8
        assert json.loads((out / "metrics.json").read_text()).keys() == expected
