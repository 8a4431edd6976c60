"""The one-pass student (unica_train.distil): its sampler is one conditional DDIM step
from t = 999, distillation moves it toward the teacher's samples, a run resumes where it
stopped, the bundle it writes runs the student by default, and bad inputs end in one
line naming the file."""

import json
import os

import pytest
import torch

from unica_train import bundle, recentre
from unica_train.diffusion import Schedule, frame_cfg_scales, frame_idle_scales, sample_next
from unica_train.distil import (RELEASE_WINDOW, DistilError, Teacher, main, one_pass, pick_frames, rollout_pool,
                                x0_prediction)

from test_train import trained_bundle_with_refiner

QUICK = ["--held-out-clips", "2", "--frames", "16", "--held-out-frames", "8", "--batch", "4", "--checkpoint-every", "2"]


@pytest.fixture(scope="module")
def teacher_bundle(tmp_path_factory):
    """A tiny trained bundle whose sampler guides, brakes (stops and turns) and draws
    scaled noise as the shipped one does."""
    tmp = tmp_path_factory.mktemp("teacher")
    from conftest import FIXTURES

    first, _ = trained_bundle_with_refiner(FIXTURES / "dataset_quick", tmp)
    vae, unet, extra, manifest = bundle.load(first / "bundle")
    manifest["sampler"].update({"ddim_steps": 4, "cfg_scale": 3.5, "idle_cfg_scale": 1.5, "idle_brake_cfg_scale": 5.0,
                                "idle_brake_frames": 10, "turn_brake_cfg_scale": 1.25, "turn_brake_frames": 5,
                                "guide_idle": False, "noise_scale": 0.25})
    # Two training steps leave the output layer near zero, where every sampler gives the
    # same frame; a random output layer makes the 4-step guided sampler differ from one step.
    with torch.no_grad():
        unet.conv_out.weight.normal_(0, 0.05, generator=torch.Generator().manual_seed(0))
    bundle.save(first / "bundle", vae, unet, extra, manifest)
    return first / "bundle"


def test_one_pass_is_one_conditional_ddim_step_from_the_top(teacher_bundle):
    _, unet, _, _ = bundle.load(teacher_bundle)
    unet.eval()
    gen = torch.Generator().manual_seed(3)
    context = torch.randn(3, 3, 4, 16, 16, generator=gen)
    action = torch.tensor([0, 1, 4])
    noise = 0.25 * torch.randn(3, 4, 16, 16, generator=gen)
    schedule = Schedule()
    with torch.no_grad():
        got = one_pass(unet, schedule, context, action, noise)
        # x0 = (x_T - sqrt(1 - a) eps) / sqrt(a) at t = 999, conditional only
        eps = unet(torch.cat([context, noise[:, None]], 1), torch.tensor([[0, 0, 0, 999]] * 3), action)[:, -1]
        a = schedule.alpha_bar(torch.tensor(999))
        want = (noise - (1 - a).sqrt() * eps) / a.sqrt()
        assert torch.allclose(got, want, atol=1e-4), (got - want).abs().max()
        assert torch.allclose(x0_prediction(unet, schedule, context, noise, torch.full((3,), 999), action), want, atol=1e-4)
        # t = -1 is the consistency boundary: the sample itself
        assert torch.equal(x0_prediction(unet, schedule, context, noise, torch.full((3,), -1), action), noise)
        assert torch.allclose(got, sample_next(unet, schedule, context, action, 1, 1.0, noise=noise), atol=1e-5)


def test_the_pool_takes_the_live_loops_guidance_for_each_frame(teacher_bundle, quick_dataset_dir):
    t = Teacher(teacher_bundle, quick_dataset_dir, [], [2])
    frames = t.frames(held_out=False)
    assert frames and all(c != 2 and f >= 3 for c, f in frames)
    # The quick dataset's clips never stop: clip 3 gets D for 12 frames (a turn from rest),
    # then Idle (the scales depend on the keys only).
    t.ds.clips[3]["actions"] = torch.tensor([4] * 12 + [0] * 14)
    picks = [x for x in frames if x[0] == 3]
    part = t.encode(picks)
    scales = part["idle_scale"].tolist()
    assert scales.count(5.0) == 10 and scales[-1] == 1.5, scales  # 10 braking frames, then at rest
    for (clip, f), scale in zip(picks, part["idle_scale"].tolist()):
        history = [int(a) for a in t.ds.clips[clip]["actions"][:f]]
        want = frame_idle_scales(history, 1.5, 5.0, 10)[-1]
        assert scale == want  # used only where the action is Idle (diffusion.guided_eps)
    # The turn's first 5 frames at the turn-braking scale (frames 3-5 have three before
    # them), every other at the keys'.
    cfgs = part["cfg_scale"].tolist()
    for (clip, f), cfg in zip(picks, cfgs):
        assert cfg == (1.25 if f <= 5 else 3.5), (f, cfg)
    assert part["context"].shape[1:] == (3, 4, 16, 16) and part["truth"].shape[1:] == (4, 16, 16)
    # The teacher samples each frame at its own scale: as sample_next at that scale alone.
    rows = [0, 5]  # frames 3 (turning) and 8 (not)
    noise = 0.25 * torch.randn(2, 4, 16, 16, generator=torch.Generator().manual_seed(1))
    got = t.sample(part["context"][rows], part["action"][rows], part["idle_scale"][rows], noise,
                   frame_cfg=part["cfg_scale"][rows])
    for k, (r, cfg) in enumerate(zip(rows, (1.25, 3.5))):
        want = sample_next(t.unet, t.schedule, part["context"][[r]], part["action"][[r]], t.steps, cfg, noise=noise[[k]],
                           **t.options)
        assert torch.allclose(got[k], want[0], atol=1e-5), k
    assert not torch.allclose(got, t.sample(part["context"][rows], part["action"][rows], part["idle_scale"][rows], noise))


def test_release_share_draws_that_share_from_the_frames_after_a_key_is_released(teacher_bundle, quick_dataset_dir):
    t = Teacher(teacher_bundle, quick_dataset_dir, [], [2])
    # Clip 3: W for 12 frames, then Idle (released at frame 12); clip 1: Idle, then W
    # (a start, not a release).
    t.ds.clips[3]["actions"], t.ds.clips[3]["switch"] = torch.tensor([1] * 12 + [0] * 14), 12
    t.ds.clips[1]["actions"], t.ds.clips[1]["switch"] = torch.tensor([0] * 12 + [1] * 14), 12
    released = {x for x in t.frames(held_out=False) if t.after_release(*x)}
    assert released == {(3, f) for f in range(12, min(26, 12 + RELEASE_WINDOW))}, sorted(released)
    picks = pick_frames(t, 40, seed=0, held_out=False, release_share=0.25)
    assert all(x in released for x in picks[:10]), picks[:10]
    assert sum(x in released for x in picks) < 40
    # Without the option the pool is drawn as before (the same picks from the same seed).
    assert pick_frames(t, 40, 0, False) == pick_frames(t, 40, 0, False, 0.0)


def test_from_student_starts_from_the_bundles_student(teacher_bundle, quick_dataset_dir, tmp_path):
    first = tmp_path / "first"
    main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(first), "--steps", "3",
          "--lr", "1e-3", *QUICK])
    # Zero steps from the first run's student: the written student is that student.
    again = tmp_path / "again"
    main(["--bundle", str(first / "bundle"), "--data", str(quick_dataset_dir), "--out", str(again), "--steps", "1",
          "--lr", "0", "--from-student", "--release-share", "0.5", *QUICK])
    _, _, extra1, _ = bundle.load(first / "bundle")
    _, _, extra2, manifest = bundle.load(again / "bundle")
    _, teacher_unet, _, _ = bundle.load(teacher_bundle)
    keys = [k for k in extra1 if k.startswith("student.")]
    assert keys and all(torch.allclose(extra1[k], extra2[k], rtol=1e-3, atol=1e-6) for k in keys)
    teacher = teacher_unet.state_dict()
    assert any(not torch.allclose(extra2[k], teacher[k[len("student."):]]) for k in keys), "the teacher, not the student"
    assert manifest["metrics"]["one_pass"]["from_student"] is True
    # A bundle without a student is refused in one line naming it.
    with pytest.raises(SystemExit) as e:
        main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(tmp_path / "none"),
              "--steps", "1", "--from-student", *QUICK])
    assert str(teacher_bundle) in str(e.value) and "no student" in str(e.value) and "\n" not in str(e.value)


def test_direct_distillation_moves_the_student_to_the_teachers_samples_and_resumes(teacher_bundle, quick_dataset_dir,
                                                                                   tmp_path, capsys):
    out = tmp_path / "run"
    main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(out), "--steps", "4",
          "--lr", "1e-4", *QUICK])
    first = json.loads((out / "metrics.json").read_text())["held_out"]
    # Interrupted work resumes: the pool and the teacher's samples are kept, training goes on.
    stamps = {p: p.stat().st_mtime_ns for p in (out / "pool").iterdir()}
    capsys.readouterr()
    main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(out), "--steps", "40",
          "--lr", "1e-4", "--resume", *QUICK])
    log = capsys.readouterr().out
    assert "resumed at step 4" in log and "pool [" not in log and "teacher [" not in log, log
    assert {p: p.stat().st_mtime_ns for p in (out / "pool").iterdir()} == stamps
    metrics = json.loads((out / "metrics.json").read_text())
    held = metrics["held_out"]
    # On the held-out frames the student is nearer the teacher's samples than where it
    # started (the teacher UNet's one pass), and nearer after 40 steps than after 4.
    assert held["student_one_pass"]["latent_rms_to_teacher"] < 0.95 * held["teacher_one_pass"]["latent_rms_to_teacher"], held
    assert held["student_one_pass"]["latent_rms_to_teacher"] < first["student_one_pass"]["latent_rms_to_teacher"], (first, held)
    assert held["teacher"]["latent_rms_to_teacher"] == 0
    # The bundle: the teacher as it was, the student beside it, one pass by default.
    vae, unet, extra, manifest = bundle.load(out / "bundle")
    _, unet0, extra0, manifest0 = bundle.load(teacher_bundle)
    assert all(torch.equal(v, unet.state_dict()[k]) for k, v in unet0.state_dict().items())
    assert manifest["sampler"] == dict(manifest0["sampler"], kind="one_pass")
    assert manifest["metrics"]["one_pass"]["method"] == "direct"
    student, steps, cfg = bundle.live_sampler(manifest, unet, extra)
    assert (steps, cfg) == (1, 1.0) and student is not unet
    moved = max((student.state_dict()[k] - v).abs().max().item() for k, v in unet0.state_dict().items() if v.is_floating_point())
    assert moved > 0
    assert not any(p.name.endswith(".tmp") for p in out.rglob("*")), "no half-written file is left"


def test_truth_weight_one_pulls_the_student_to_the_true_frames_without_teacher_samples(teacher_bundle,
                                                                                      quick_dataset_dir, tmp_path,
                                                                                      capsys):
    out = tmp_path / "truth"
    main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(out), "--steps", "40",
          "--lr", "1e-4", "--truth-weight", "1", *QUICK])
    log = capsys.readouterr().out
    # The pool's frames are never sampled by the teacher (only the held-out ones, to score).
    assert "teacher [" not in log and "teacher (held out) [" in log, log
    assert not (out / "teacher").exists()
    metrics = json.loads((out / "metrics.json").read_text())
    held = metrics["held_out"]
    assert metrics["truth_weight"] == 1.0
    # On held-out frames the student is nearer the truth than where it started.
    start = held["teacher_one_pass"]["latent_rms_to_truth"]
    assert held["student_one_pass"]["latent_rms_to_truth"] < 0.95 * start, held
    with pytest.raises(SystemExit):
        main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(tmp_path / "bad"),
              "--truth-weight", "1.5", *QUICK])
    assert "--truth-weight must be between 0 and 1" in capsys.readouterr().err


def test_consistency_distillation_runs_and_writes_a_one_pass_bundle(teacher_bundle, quick_dataset_dir, tmp_path):
    out = tmp_path / "cd"
    main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(out), "--method", "consistency",
          "--steps", "2", *QUICK])
    _, unet, extra, manifest = bundle.load(out / "bundle")
    assert manifest["sampler"]["kind"] == "one_pass" and manifest["metrics"]["one_pass"]["method"] == "consistency"
    assert not (out / "teacher").exists(), "consistency distillation needs no stored teacher samples"


def test_bad_inputs_end_in_one_line_naming_the_file(teacher_bundle, quick_dataset_dir, tmp_path):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "something").write_text("x")
    with pytest.raises(SystemExit) as e:
        main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(out), *QUICK])
    assert str(out) in str(e.value) and "--resume" in str(e.value)
    with pytest.raises(SystemExit) as e:
        main(["--bundle", str(tmp_path / "nowhere"), "--data", str(quick_dataset_dir), "--out", str(tmp_path / "a"), *QUICK])
    assert "nowhere" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(SystemExit) as e:
        main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(tmp_path / "b"),
              "--held-out-clips", "99", "--frames", "4"])
    assert "held-out" in str(e.value) and "\n" not in str(e.value)
    # A manifest naming an unknown sampler kind is refused by name.
    manifest = json.loads((teacher_bundle / "manifest.json").read_text())
    _, unet, extra, _ = bundle.load(teacher_bundle)
    with pytest.raises(bundle.BundleError, match="two_pass"):
        bundle.live_sampler(dict(manifest, sampler=dict(manifest["sampler"], kind="two_pass")), unet, extra)
    with pytest.raises(bundle.BundleError, match="student"):
        bundle.live_sampler(dict(manifest, sampler=dict(manifest["sampler"], kind="one_pass")), unet, extra)
    assert os.path.isdir(teacher_bundle)


def test_rollout_frames_are_the_live_loops_own_contexts_under_the_teachers_guidance(teacher_bundle, quick_dataset_dir,
                                                                                   tmp_path):
    first = tmp_path / "first"
    main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(first), "--steps", "3",
          "--lr", "1e-3", *QUICK])
    t = Teacher(first / "bundle", quick_dataset_dir, [], [2])
    t.ds.clips[3]["actions"] = torch.tensor([4] * 12 + [0] * 14)  # D from rest, then Idle: turns and brakes
    t.held_out = set(range(len(t.ds.clips))) - {3}  # clip 3 alone is rolled out
    part = rollout_pool(t, tmp_path / "rolled.safetensors", 7, seed=5, held_out=False, stride=3, label="ro")
    frames = part["frames"].tolist()
    offset = frames[0][1]
    assert [f for _, f in frames] == [offset + 3 * k for k in range(7)] and {c for c, _ in frames} == {3}, frames
    # The contexts are the loop's own from its standing start, the student's frames fed
    # back (the same rollout seen from outside), not the teacher UNet's.
    seen = {}
    for model, name in ((bundle.live_sampler(t.manifest, t.unet, t.extra)[0], "student"), (t.unet, "teacher")):
        contexts = {}
        recentre.rollout(t.vae, model, t.schedule, t.latent_scale, t.extra["context.latents"], [4] * 12 + [0] * 14, 1, 1.0,
                         5 + 100, t.ds.pixels, t.extra["map.waist"].long(), t.manifest["normalisation"]["scale"],
                         "reencode", frames=frames[-1][1] + 1, on_context=lambda i, c, a: contexts.__setitem__(i, (c.clone(), a)),
                         root_motion=t.manifest.get("root_motion", "centre"), heading=t.heading,
                         grounded=bool(t.manifest.get("grounded", False)), stand_speed=t.manifest.get("stand_speed"),
                         frame_rate=float(t.manifest["frame_rate"]), **t.options, **t.brake)
        seen[name] = contexts
    for k, (_, f) in enumerate(frames):
        context, action = seen["student"][f]
        assert torch.equal(part["context"][k], context) and int(part["action"][k]) == action, f
    assert not torch.allclose(part["context"][-1], seen["teacher"][frames[-1][1]][0]), "the teacher UNet's rollout"
    # Each frame carries the guidance the teacher's sampler would use after those keys.
    keys = [4] * 12 + [0] * 14
    for k, (_, f) in enumerate(frames):
        assert float(part["idle_scale"][k]) == frame_idle_scales(keys[:f + 1], 1.5, 5.0, 10)[-1]
        assert float(part["cfg_scale"][k]) == frame_cfg_scales(keys[:f + 1], 3.5, 1.25, 5)[-1]
    assert part["noise"].shape == (7, 4, 16, 16) and 0.1 < float(part["noise"].std()) < 0.4  # the sampler's 0.25
    # The same file asked for with other options is refused, not reused under them.
    with pytest.raises(DistilError, match="other rollout options"):
        rollout_pool(t, tmp_path / "rolled.safetensors", 7, seed=5, held_out=False, stride=2, label="ro")
    # Held out, every frame is kept but the standing start that every rollout shares.
    t.held_out = {3}
    held = rollout_pool(t, tmp_path / "held.safetensors", 4, seed=5, held_out=True, stride=1, label="ho")
    assert [f for _, f in held["frames"].tolist()] == [1, 2, 3, 4]
    # A run with rollout frames trains on them, scores held-out rollouts, and resumes
    # without rolling out again.
    out = tmp_path / "run"
    args = ["--bundle", str(first / "bundle"), "--data", str(quick_dataset_dir), "--out", str(out), "--from-student",
            "--rollout-frames", "8", "--rollout-held-out-frames", "4", "--rollout-stride", "2", *QUICK]
    main([*args, "--steps", "2"])
    stamp = (out / "rollout" / "pool.safetensors").stat().st_mtime_ns
    main([*args, "--steps", "3", "--resume"])
    assert (out / "rollout" / "pool.safetensors").stat().st_mtime_ns == stamp
    record = json.loads((out / "metrics.json").read_text())
    assert record["rollout_frames"] == 8 and set(record["held_out_rollouts"]) == {"bundle_student", "student_one_pass"}
    assert all(v["mm_to_teacher"] > 0 for v in record["held_out_rollouts"].values())
    with pytest.raises(SystemExit):
        main([*args[:5], str(tmp_path / "cd"), *args[6:], "--method", "consistency"])
    with pytest.raises(SystemExit) as e:
        main(["--bundle", str(teacher_bundle), "--data", str(quick_dataset_dir), "--out", str(tmp_path / "none"),
              "--rollout-frames", "4", *QUICK])
    assert str(teacher_bundle) in str(e.value) and "no student" in str(e.value) and "\n" not in str(e.value)
