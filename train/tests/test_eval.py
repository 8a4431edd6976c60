"""`unica eval --quick` end to end: the shipped Witch bundle against a short dataset baked
from assets/witch/source/Witch.gltf with renders (the binary from `cargo test
--release`, which the README's test command runs first)."""

import json
import math
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BINARY = ROOT / "target" / "release" / "unica"
WITCH = ROOT / "assets" / "witch" / "source" / "Witch.gltf"


def test_unica_eval_quick_writes_a_report_with_finite_numbers(tmp_path):
    assert BINARY.is_file(), f"{BINARY} is missing: run `cargo build --release` (the README's test command does)"
    assert WITCH.is_file(), f"{WITCH} is missing: the Witch ships in assets/witch/source"
    data, out = tmp_path / "data", tmp_path / "report"
    subprocess.run([str(BINARY), "bake", str(WITCH), "--out", str(data), "--quick"], check=True, cwd=ROOT)
    subprocess.run([str(BINARY), "eval", "--bundle", "assets/witch/bundle", "--data", str(data), "--out", str(out), "--quick"],
                   check=True, cwd=ROOT)
    for name in ("report.md", "results.json", "turns.png", "drift.png", "ablations.png", "contact_sheet.png"):
        assert (out / name).is_file(), name
    results = json.loads((out / "results.json").read_text())
    image = results["image"]["metrics"]
    assert image["ground truth, refined"]["psnr"] > image["ground truth, base"]["psnr"], image
    seq = results["sequence"]
    assert math.isfinite(seq["chamfer_mm"]) and 0 < seq["chamfer_mm"] < 200
    assert math.isfinite(seq["fvd_pca"])
    assert [s["key"] for s in seq["segments"]][:3] == ["W", "S", "A"]
    assert results["long_run"]["finite"]
    assert "| steps=1 |" in (out / "report.md").read_text()
