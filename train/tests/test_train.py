"""The whole training pipeline end to end on the quick fixture with a tiny config: every
stage runs, resumes, and writes a bundle that loads."""

import json

import pytest
import torch
from safetensors.torch import load_file

from unica_train import bundle
from unica_train.train import main, parse_keys

TINY = {
    "vae": {"channels": [16, 12, 8, 8], "latent": 4, "kl_weight": 1e-6},
    "unet": {"latent": 4, "channels": [16, 32], "embed": 32, "heads": 2, "frames": 4, "actions": 5},
    "vae_steps": 4, "vae_batch": 2, "unet_steps": 4, "stage2_steps": 2, "unet_batch": 2,
    "pca_components": 8, "pca_frames": 20, "held_out_clips": [2], "rollout_frames": 3,
    "ddim_steps": 2, "checkpoint_every": 2,
}


def test_keys_parse_like_the_app():
    assert parse_keys("2W 1D", 5) == [1, 1, 4, 0, 0]


def test_the_make_config_gives_a_new_avatar_the_shipped_witchs_live_settings():
    # `unica make` trains from train/configs/make_full.json; the manifest entries the live
    # loop reads must come out as the shipped Witch's, whose were chosen by measurement
    # (docs/experiments/motion.md).
    from pathlib import Path

    from unica_train.train import TrainConfig

    root = Path(__file__).resolve().parents[2]
    live = TrainConfig(**json.loads((root / "train/configs/make_full.json").read_text())).live()
    witch = json.loads((root / "assets/witch/bundle/manifest.json").read_text())
    for key in ("root_motion", "heading", "grounded", "stand_speed"):
        assert live[key] == witch[key], key
    for key in ("ddim_steps", "cfg_scale", "guide_idle", "noise_scale", "idle_brake_cfg_scale", "idle_brake_frames",
                "turn_brake_cfg_scale", "turn_brake_frames"):
        assert live["sampler"].get(key) == witch["sampler"].get(key), key
    # The defaults are the settings of bundles made before them: no entry changes meaning.
    assert TrainConfig().live() == {"sampler": {"ddim_steps": 10, "cfg_scale": 1.0, "guide_idle": True, "noise_scale": 1.0},
                                    "root_motion": "centre", "grounded": False, "heading": "world"}
    for bad in ({"root_motion": "centred"}, {"stand_speed": -0.1}, {"noise_scale": 0.0}, {"turn_brake_frames": -1}):
        with pytest.raises(ValueError):
            TrainConfig(**bad)


def test_progress_bar():
    from unica_train.train import bar

    assert bar(5, 10, width=10) == "[#####-----]  50%"
    assert bar(10, 10, width=4) == "[####] 100%"


def test_training_end_to_end_and_resume(quick_dataset_dir, tmp_path, capsys):
    config = tmp_path / "tiny.json"
    config.write_text(json.dumps(TINY))
    out = tmp_path / "run"
    main(["--data", str(quick_dataset_dir), "--out", str(out), "--config", str(config)])
    vae, unet, extra, manifest = bundle.load(out / "bundle")
    assert manifest["avatar"] == "Witch" and manifest["pca"]["components"] == 8
    assert extra["context.latents"].shape == (3, 4, 16, 16)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["vae_reconstruction_mm"] > 0
    rollout = json.loads((out / "rollout.json").read_text())
    assert len(rollout["root_path"]) == 4
    assert (out / "curves.png").read_bytes()[:4] == b"\x89PNG"
    # Resuming a finished run picks up every stage at its last step and trains no more.
    capsys.readouterr()
    main(["--data", str(quick_dataset_dir), "--out", str(out), "--config", str(config), "--resume"])
    log = capsys.readouterr().out
    assert "resumed vae at step 4" in log and "resumed unet at step 6" in log
    assert "] 1/" not in log and "] 2/" not in log, "nothing retrained"
    bundle.load(out / "bundle")


def test_training_with_a_pca_head_decoder_writes_its_basis(quick_dataset_dir, tmp_path):
    config = tmp_path / "pca.json"
    cfg = dict(TINY, vae={**TINY["vae"], "decoder": "pca", "components": 6}, unet_steps=2, stage2_steps=0)
    config.write_text(json.dumps(cfg))
    main(["--data", str(quick_dataset_dir), "--out", str(tmp_path / "run"), "--config", str(config)])
    vae, _, extra, manifest = bundle.load(tmp_path / "run" / "bundle")
    assert manifest["vae"]["decoder"] == "pca" and manifest["vae"]["components"] == 6
    assert torch.equal(vae.decoder.pixels, extra["map.pixels"])
    basis = vae.decoder.basis
    # Stored as int8: each value is within half its group's step of the orthonormal basis
    # the trainer made, so row i moves at most r_i = |half steps of row i| and
    # |B B^T - I|_ij <= r_i + r_j + r_i r_j.
    scale = load_file(str(tmp_path / "run" / "bundle" / "weights.safetensors"))["vae.decoder.basis" + bundle.SCALE]
    step = scale.float().repeat_interleave(bundle.QUANT_GROUP)[: basis.numel()].reshape(basis.shape)
    r = (step / 2).square().sum(1).sqrt()
    bound = r[:, None] + r[None, :] + r[:, None] * r[None, :]
    assert ((basis @ basis.T - torch.eye(6)).abs() <= bound + 1e-6).all()
    assert bound.max() < 0.02, "the int8 steps are too coarse to call this basis orthonormal"
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["vae_decoder_gflop"] > 2 * basis.numel() / 1e9


def test_path_comparison_splits_the_script_into_legs():
    from unica_train.compare import compare, segments

    assert segments("2W 1D", 5) == [("W", 0, 2), ("D", 2, 3), ("I", 3, 5)]
    # A path going 1 m along +Z in 30 frames, then 1 m along -X.
    path = [[0, 0, i / 30] for i in range(31)] + [[-i / 30, 0, 1] for i in range(1, 31)]
    rows = compare({"keys": "30W 30D", "root_path": path}, path)
    assert rows[0]["model"] == {"dx": 0.0, "dz": 1.0, "distance_m": 1.0, "heading_deg": 0.0, "speed_m_s": 1.0}
    assert rows[1]["teacher"]["heading_deg"] == -90.0


def test_point_sheet_draws_each_cloud_in_its_tile(tmp_path):
    import zlib

    from unica_train.plot import point_sheet

    point_sheet(tmp_path / "s.png", [[[0, 0, 0], [1, 1, 0]], [[0, 0, 0], [0, 2, 0]]], tile=50)
    data = (tmp_path / "s.png").read_bytes()
    assert data[:4] == b"\x89PNG"
    width = int.from_bytes(data[16:20], "big")
    assert width == 100
    idat = data[data.index(b"IDAT") + 4: data.index(b"IEND") - 8]
    rows = zlib.decompress(idat)
    assert rows.count(bytes([230, 230, 230])) >= 4


def _rank(rank, world, port, argv):
    import os

    os.environ.update({"RANK": str(rank), "LOCAL_RANK": str(rank), "WORLD_SIZE": str(world), "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port)})
    main(argv)


def test_two_process_data_parallel_training_stays_in_sync(quick_dataset_dir, tmp_path, capfd):
    import socket

    import torch.multiprocessing as mp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    config = tmp_path / "tiny.json"
    config.write_text(json.dumps(TINY))
    out = tmp_path / "ddp"
    argv = ["--data", str(quick_dataset_dir), "--out", str(out), "--config", str(config), "--device", "cpu"]
    mp.spawn(_rank, args=(2, port, argv), nprocs=2, join=True)
    assert "parameters in sync across 2 processes" in capfd.readouterr().out
    bundle.load(out / "bundle")


def trained_bundle_with_refiner(data, tmp_path):
    """A tiny run's bundle (2 UNet steps) with a tiny refiner added: (its run folder, the
    config it was trained with)."""
    from unica_train.fixtures import TINY_REFINER
    from unica_train.refiner import Refiner, add_to_bundle

    config = tmp_path / "tiny.json"
    config.write_text(json.dumps(dict(TINY, unet_steps=2, stage2_steps=0)))
    first = tmp_path / "first"
    main(["--data", str(data), "--out", str(first), "--config", str(config)])
    add_to_bundle(first / "bundle", Refiner(TINY_REFINER))
    return first, config


def test_init_continues_a_bundle_keeping_its_vae_and_refiner(quick_dataset_dir, tmp_path, capsys):
    first, config = trained_bundle_with_refiner(quick_dataset_dir, tmp_path)
    vae0, unet0, extra0, manifest0 = bundle.load(first / "bundle")
    capsys.readouterr()
    second = tmp_path / "second"
    main(["--data", str(quick_dataset_dir), "--out", str(second), "--config", str(config), "--init", str(first / "bundle")])
    log = capsys.readouterr().out
    assert "started from the --init bundle's weights" in log and "vae [" not in log, "the VAE is not trained again"
    vae1, unet1, extra1, manifest1 = bundle.load(second / "bundle")
    for k, v in vae0.state_dict().items():
        assert torch.equal(v, vae1.state_dict()[k]), k
    assert manifest1["refiner"] == manifest0["refiner"]
    refiner = {k: v for k, v in extra0.items() if k.startswith("refiner.")}
    assert refiner and all(torch.equal(v, extra1[k]) for k, v in refiner.items())
    assert manifest1["latent_scale"] == manifest0["latent_scale"]
    # The UNet was trained on from the first bundle's: two more steps moved it a little.
    moved = [(unet1.state_dict()[k] - v).abs().max().item() for k, v in unet0.state_dict().items() if v.is_floating_point()]
    assert 0 < max(moved) < 0.1


def test_unet_only_replaces_just_the_unet_and_a_time_budget_shortens_its_schedule(quick_dataset_dir, tmp_path, capsys):
    first, _ = trained_bundle_with_refiner(quick_dataset_dir, tmp_path)
    manifest = json.loads((first / "bundle" / "manifest.json").read_text())
    manifest["sampler"]["idle_cfg_scale"] = 1.5  # a setting the trainer never writes
    (first / "bundle" / "manifest.json").write_text(json.dumps(manifest))
    vae0, unet0, extra0, manifest0 = bundle.load(first / "bundle")
    # 1,000 steps cannot fit in 0.01 minutes: after 30 steps the schedule is cut, stage 2 in proportion.
    budget = tmp_path / "budget.json"
    budget.write_text(json.dumps(dict(TINY, unet_steps=800, stage2_steps=200, checkpoint_every=1000, unet_minutes=0.01)))
    second = tmp_path / "second"
    capsys.readouterr()
    main(["--data", str(quick_dataset_dir), "--out", str(second), "--config", str(budget),
          "--init", str(first / "bundle"), "--unet-only"])
    log = capsys.readouterr().out
    schedule = json.loads((second / "unet_schedule.json").read_text())
    assert 30 <= schedule["unet_steps"] + schedule["stage2_steps"] < 1000, schedule
    assert schedule["unet_steps"] == round(800 * (schedule["unet_steps"] + schedule["stage2_steps"]) / 1000)
    assert "steps fit in 0.01 min" in log and "pca" not in log.lower().split("unet: the bundle")[-1]
    vae1, unet1, extra1, manifest1 = bundle.load(second / "bundle")
    assert manifest1["sampler"] == manifest0["sampler"] and manifest1["latent_scale"] == manifest0["latent_scale"]
    assert manifest1["pca"] == manifest0["pca"] and manifest1["refiner"] == manifest0["refiner"]
    assert set(extra1) == set(extra0) and all(torch.equal(v, extra1[k]) for k, v in extra0.items())
    assert all(torch.equal(v, vae1.state_dict()[k]) for k, v in vae0.state_dict().items())
    moved = [(unet1.state_dict()[k] - v).abs().max().item() for k, v in unet0.state_dict().items() if v.is_floating_point()]
    assert max(moved) > 0
    metrics = json.loads((second / "metrics.json").read_text())
    assert set(metrics["denoise_mse_before"]) == {"t100", "t500", "t900"} and metrics["denoise_mse"] != metrics["denoise_mse_before"]
    assert metrics["unet_schedule"] == schedule and manifest1["metrics"]["denoise_mse"] == metrics["denoise_mse"]
    assert not (second / "rollout.json").exists()
    with pytest.raises(SystemExit):
        main(["--data", str(quick_dataset_dir), "--out", str(tmp_path / "x"), "--unet-only"])


def test_ridge_recovers_an_exact_linear_map():
    from unica_train.refit import ridge

    gen = torch.Generator().manual_seed(3)
    x = torch.randn(200, 6, generator=gen)
    w_true, b_true = torch.randn(4, 6, generator=gen), torch.randn(4, generator=gen)
    w, b = ridge(x, x @ w_true.T + b_true, 0.0)
    torch.testing.assert_close(w.float(), w_true, atol=1e-5, rtol=0)
    torch.testing.assert_close(b.float(), b_true, atol=1e-5, rtol=0)
    # The penalty per 1,000 rows: x = ±1 (mean 0), y = 2x + 3 gives w = 2 / (1 + p / 1000)
    # and the bias, never penalised, 3. Zero-weight rows do not count.
    x1 = torch.tensor([[1.0], [-1.0]] * 50)
    w, b = ridge(x1, 2 * x1 + 3, 1000.0)
    assert abs(float(w) - 1.0) < 1e-9 and abs(float(b) - 3.0) < 1e-9
    noisy = torch.cat([x @ w_true.T + b_true, torch.randn(50, 4, generator=gen)])
    weights = torch.cat([torch.ones(200), torch.zeros(50)])
    w, _ = ridge(torch.cat([x, torch.randn(50, 6, generator=gen)]), noisy, 0.0, weights)
    torch.testing.assert_close(w.float(), w_true, atol=1e-5, rtol=0)


def test_refit_replaces_the_head_with_the_least_squares_one(quick_dataset_dir, tmp_path):
    from unica_train import refit

    config = tmp_path / "pca.json"
    cfg = dict(TINY, vae={**TINY["vae"], "decoder": "pca", "components": 6}, unet_steps=2, stage2_steps=0)
    config.write_text(json.dumps(cfg))
    main(["--data", str(quick_dataset_dir), "--out", str(tmp_path / "run"), "--config", str(config)])
    old = tmp_path / "run" / "bundle"
    new = tmp_path / "refit"
    refit.main(["--bundle", str(old), "--data", str(quick_dataset_dir), "--out", str(new), "--held-out", "2",
                "--generated-weight", "0", "--ridge", "0", "--encoder-stride", "1", "--generated-stride", "4"])
    report = json.loads((new / "refit.json").read_text())
    vae_old, unet_old, _, _ = bundle.load(old)
    vae_new, unet_new, _, manifest = bundle.load(new)
    assert manifest["metrics"]["vae_reconstruction_mm"] == report["after"]["vae_reconstruction_mm"]
    assert not torch.equal(vae_old.decoder.head.weight, vae_new.decoder.head.weight)
    assert torch.equal(unet_old.state_dict()["conv_in.weight"], unet_new.state_dict()["conv_in.weight"])
    # With no penalty and the encoder's latents alone, the new head is the least-squares
    # one: on its training frames no head (the trainer's included) reconstructs better.
    fit = refit.Fit(old, quick_dataset_dir, tmp_path / "scratch", [2])
    z, c = fit.encoded(fit.run.train_groups)
    after = fit.error_mm(vae_new.decoder.head.weight, vae_new.decoder.head.bias, z, c)
    before = fit.error_mm(vae_old.decoder.head.weight, vae_old.decoder.head.bias, z, c)
    assert after < before
    import pytest

    with pytest.raises(SystemExit, match="another folder"):
        refit.main(["--bundle", str(old), "--data", str(quick_dataset_dir), "--out", str(old)])
    with pytest.raises(SystemExit, match="no-such-bundle"):
        refit.main(["--bundle", str(tmp_path / "no-such-bundle"), "--data", str(quick_dataset_dir), "--out", str(new)])


def test_quarter_turns_encode_every_training_group_turned_and_turn_its_action(quick_dataset_dir, tmp_path):
    from unica_train.dataset import quarter_turn_action
    from unica_train.train import Run, TrainConfig

    cfg = TrainConfig(**dict(TINY, quarter_turns=True, unet_steps=2, stage2_steps=1))
    (tmp_path / "checkpoints").mkdir()
    run = Run(quick_dataset_dir, tmp_path, cfg, torch.device("cpu"))
    vae = run.train_vae(False)
    latents, scale = run.encode_groups(vae)
    assert run.turned.shape == (3, *latents.shape)
    held = run.test_groups[0]
    assert not run.turned[:, held].any(), "held-out groups are not turned into training"
    i = run.train_groups[len(run.train_groups) // 2]
    with torch.no_grad():
        for turns in (1, 2, 3):
            expected = vae.encoder(run.group_maps(i, turns))[0]
            torch.testing.assert_close(run.turned[turns - 1, i], expected, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(run.group_maps(i, 4), run.group_maps(i, 0))
    assert not torch.allclose(run.turned[0, i], latents[i], atol=1e-3), "a turned group is another group"
    # The scale is the unturned groups' (what a bundle without turns would have).
    assert scale == pytest.approx(float(1.0 / latents[run.train_groups].std()))
    # A second call reads the cache, turned latents included.
    cached = Run(quick_dataset_dir, tmp_path, cfg, torch.device("cpu"))
    again, _ = cached.encode_groups(vae)
    assert torch.equal(again, latents) and torch.equal(cached.turned, run.turned)
    unet, _ = run.train_unet(latents, scale, False)
    assert all(torch.isfinite(p).all() for p in unet.parameters())
    assert [quarter_turn_action(a) for a in range(5)] == [0, 3, 4, 2, 1]


def test_extra_data_joins_the_training_clips_after_the_main_ones(quick_dataset_dir, tmp_path):
    import shutil

    from safetensors.torch import load_file, save_file

    from unica_train.dataset import DatasetError
    from unica_train.train import Run, TrainConfig

    more = tmp_path / "more"
    shutil.copytree(quick_dataset_dir, more)
    cfg = TrainConfig(**TINY)
    (tmp_path / "checkpoints").mkdir()
    alone = Run(quick_dataset_dir, tmp_path, cfg, torch.device("cpu"))
    both = Run(quick_dataset_dir, tmp_path, cfg, torch.device("cpu"), extra=[more])
    n = len(alone.ds.clips)
    assert len(both.ds.clips) == 2 * n and len(both.groups) == 2 * len(alone.groups)
    # The held-out clips are the main dataset's; every extra group trains.
    assert both.test_groups == alone.test_groups
    assert len(both.train_groups) == len(alone.train_groups) + len(alone.groups)
    torch.testing.assert_close(both.world[n + 1], alone.world[1])
    # Another character's clips are refused, naming the file.
    ref = load_file(str(more / "reference.safetensors"))
    ref["bind_positions"] = ref["bind_positions"] * 1.1
    save_file(ref, str(more / "reference.safetensors"))
    with pytest.raises(DatasetError, match=r"more/reference.safetensors: its bind differ"):
        Run(quick_dataset_dir, tmp_path, cfg, torch.device("cpu"), extra=[more])
