"""Masked probe of a bundle's refiner: teacher-forced on 12 held-out frames (as unica eval),
and free-running on session 23's engine rollout (same geometry model: the refiner does not change it)."""
import sys, time, json
from pathlib import Path
import torch
from unica_train import eval as ev
bundle = Path(sys.argv[1]); t0 = time.time()
av = ev.Avatar(bundle, Path("/tmp/witch-data"), 256)
frames = ev.Frames(Path("/tmp/witch-data"), bundle, 512, reconstruct=False)
out = {}
r = ev.masked_teacher_forced(av, frames, 12, 0, [])
out["tf"] = r["generated"]["black"]; out["gt"] = r["ground_truth"]["black"]
run = ev.engine_rollout(av, Path("/tmp/s23/eval/engine"))
out["free"] = ev.masked_free_running(av, frames, run, 5)["black"]
print(bundle, {k: f"{v['psnr']:.2f}/{v['ssim']:.3f}" for k, v in out.items()}, f"{time.time()-t0:.0f} s", flush=True)
