import json

from unica_train import bench


def test_bench_tiny_and_default_on_cpu(tmp_path, capsys):
    out = tmp_path / "bench.json"
    report = bench.main(["--config", "both", "--device", "cpu", "--steps", "2", "--repeat", "1", "--json", str(out)])
    assert json.loads(out.read_text()) == json.loads(json.dumps(report))
    rows = {(r["config"], r["what"]): r for r in report["rows"]}
    assert set(rows) == {(c, w) for c in ("tiny", "default") for w in ("unet step", "unet-target", "vae decode", "generated frame")}
    for row in rows.values():
        assert row["ms"] > 0 and row["gflop"] > 0 and row["gflops"] > 0
    # The default UNet is ~0.455 GFLOP per frame: the CFG batch of 2 over 4 frames is ~3.64.
    unet = rows["default", "unet step"]["gflop"]
    assert abs(unet - 2 * 4 * 0.455) < 0.05 * 3.64
    decode = rows["default", "vae decode"]["gflop"]
    assert 0.3 < decode < 0.5  # docs/architecture.md, The geometry model: the decoder stays under 0.5 GFLOP
    assert abs(rows["default", "generated frame"]["gflop"] - (2 * unet + decode)) < 1e-9
    assert rows["tiny", "unet step"]["gflop"] < unet / 10
    # unet-target is one sample of the group at CFG 1: half the CFG batch.
    assert abs(rows["default", "unet-target"]["gflop"] - unet / 2) < 1e-9
    printed = capsys.readouterr().out
    assert printed.startswith("PyTorch ") and "GFLOP/s" in printed and "generated frame" in printed
    target = rows["default", "unet-target"]
    assert f"pytorch stage unet-target: ms={target['ms']:.1f} gflops={target['gflops']:.2f}\n" in printed
