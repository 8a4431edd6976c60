"""Evaluation metrics (docs/architecture.md, Evaluation), each on cases with known answers."""

import math

import pytest
import torch

from unica_train import metrics as M


def grid(n: int, spacing: float) -> torch.Tensor:
    """n³ points on a cubic grid, about a metre from the origin."""
    r = torch.arange(n, dtype=torch.float32) * spacing
    x, y, z = torch.meshgrid(r, r, r, indexing="ij")
    return torch.stack([x, y, z], dim=-1).reshape(-1, 3) + torch.tensor([0.3, 0.9, -0.5])


def path_from_steps(dirs_deg: list[float], step: float | list[float], y: float = 1.0) -> torch.Tensor:
    """A path [len + 1, 3] from per-step headings (degrees, atan2(dx, dz)) and lengths."""
    lengths = step if isinstance(step, list) else [step] * len(dirs_deg)
    points = [(0.0, y, 0.0)]
    for h, s in zip(dirs_deg, lengths):
        x, _, z = points[-1]
        points.append((x + s * math.sin(math.radians(h)), y, z + s * math.cos(math.radians(h))))
    return torch.tensor(points, dtype=torch.float64)


# Chamfer


def test_chamfer_of_identical_clouds_is_zero():
    a = grid(6, 0.05)
    assert M.chamfer(a, a.clone()) == 0.0


def test_chamfer_of_a_small_shift_is_its_length():
    a = grid(15, 0.02)  # 3375 points
    d = torch.tensor([0.001, -0.002, 0.0015])
    assert M.chamfer(a, a + d) == pytest.approx(d.norm().item(), rel=1e-3)


def test_chamfer_is_symmetric_and_halved():
    # From a: the origin is on b (0). From b: 0 and 1, mean 0.5. Halved sum: 0.25.
    a = torch.tensor([[0.0, 0.0, 0.0]])
    b = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert M.chamfer(a, b) == pytest.approx(0.25)
    assert M.chamfer(b, a) == pytest.approx(0.25)


def test_nearest_pose_chamfer_finds_the_pose_wherever_it_stands():
    g = torch.Generator().manual_seed(0)
    poses = torch.randn(12, 200, 3, generator=g) * 0.3
    frame = poses[7] + torch.tensor([2.0, 0.0, -3.0])
    distance, index = M.nearest_pose_chamfer(frame, poses)
    assert index == 7
    assert distance == pytest.approx(0.0, abs=1e-6)
    # Without centring the same frame is metres away from every pose.
    distance, _ = M.nearest_pose_chamfer(frame, poses, centre=False)
    assert distance > 1.0


# Fréchet distance


def test_frechet_of_identical_sets_is_zero():
    x = torch.randn(300, 5, generator=torch.Generator().manual_seed(1))
    assert abs(M.frechet_distance(x, x.clone())) < 1e-6


def test_frechet_of_a_constant_shift_is_its_squared_length():
    x = torch.randn(300, 5, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    c = torch.tensor([0.5, -1.0, 0.25, 0.0, 2.0], dtype=torch.float64)
    assert M.frechet_distance(x, x + c) == pytest.approx(c.square().sum().item(), rel=1e-9)


def test_frechet_of_one_dimensional_gaussians_is_the_squared_sigma_difference():
    g = torch.Generator().manual_seed(3)
    u = torch.randn(500, 1, generator=g, dtype=torch.float64)
    v = torch.randn(400, 1, generator=g, dtype=torch.float64)
    u = (u - u.mean()) / u.std()  # unbiased standard deviation 1 exactly
    v = (v - v.mean()) / v.std()
    s1, s2 = 0.7, 1.9
    assert M.frechet_distance(s1 * u, s2 * v) == pytest.approx((s1 - s2) ** 2, rel=1e-9)


def test_windows_flatten_frame_by_frame():
    seq = torch.arange(20.0).reshape(10, 2)
    w = M.windows(seq, length=3, stride=2)
    assert w.shape == (4, 6)
    assert torch.equal(w[0], torch.tensor([0.0, 1, 2, 3, 4, 5]))
    assert torch.equal(w[3], seq[6:9].reshape(-1))


# Paths


def test_speeds_are_horizontal():
    # 0.02 m a frame along +X at 30 fps, with a vertical bob that must not count.
    t = torch.arange(11, dtype=torch.float64)
    path = torch.stack([0.02 * t, 1.0 + 0.05 * torch.sin(t), torch.zeros_like(t)], dim=1)
    assert torch.allclose(M.speeds(path, 30.0), torch.full((10,), 0.6, dtype=torch.float64))


def test_headings_follow_the_convention():
    path = path_from_steps([0.0, 90.0, 180.0, -90.0, 45.0], 0.1)
    assert torch.allclose(M.headings(path), torch.tensor([0.0, 90.0, 180.0, -90.0, 45.0], dtype=torch.float64), atol=1e-9)


def test_heading_difference_wraps_to_the_half_open_interval():
    a = torch.tensor([170.0, -170.0, 180.0, 0.0, 30.0])
    b = torch.tensor([-170.0, 170.0, -180.0, 180.0, 10.0])
    assert torch.allclose(M.heading_difference(a, b), torch.tensor([-20.0, 20.0, 0.0, 180.0, 20.0], dtype=torch.float64))
    assert M.heading_difference(-90.0, 90.0).item() == 180.0


def test_segment_summary_reports_settled_speed_and_heading():
    # Forward 40 steps along +Z at 0.03 m; Left 30 steps: 15 settling steps wandering at
    # 0.01 m, then 15 steps along -X at 0.02 m; Idle 10 steps, too short to report.
    dirs = [0.0] * 40 + [-45.0] * 15 + [-90.0] * 15 + [0.0] * 10
    steps = [0.03] * 40 + [0.01] * 15 + [0.02] * 15 + [0.0] * 10
    path = path_from_steps(dirs, steps)
    keys = [1] * 40 + [3] * 30 + [0] * 10
    runs = M.segment_summary(path, keys, frame_rate=30.0)
    assert [(r["action"], r["start"], r["frames"]) for r in runs] == [(1, 0, 40), (3, 40, 30)]
    assert runs[0]["speed"] == pytest.approx(0.9)
    assert runs[0]["heading"] == pytest.approx(0.0, abs=1e-9)
    assert runs[1]["speed"] == pytest.approx(0.6)
    assert runs[1]["heading"] == pytest.approx(-90.0)
    with pytest.raises(ValueError):
        M.segment_summary(path, keys[:-1], frame_rate=30.0)


# Responsiveness


def test_turn_frames_of_a_half_turn_over_twelve_frames():
    # 20 frames along +Z, then the key switches: the 12 steps under the new key turn by 15°
    # each (15°, 30°, ..., 180°) and the path then runs along -Z. The 11th step (165°) is
    # 15° off; the 12th (180°) is the first within 10°, and it stays: 12 frames.
    dirs = [0.0] * 20 + [15.0 * m for m in range(1, 13)] + [180.0] * 10
    path = path_from_steps(dirs, 0.05)
    switch = 21  # path[21] is the first frame the new key generates
    assert M.turn_frames(path, switch, 180.0) == 12
    # A wider tolerance takes the 165° step (the 11th) too.
    assert M.turn_frames(path, switch, 180.0, tolerance=20.0) == 11


def test_turn_frames_of_a_quarter_turn_over_nine_frames():
    # Steps of 10° (10°, ..., 90°): with a 5° tolerance only the 9th, at 90°, is on target.
    dirs = [0.0] * 20 + [10.0 * m for m in range(1, 10)] + [90.0] * 10
    path = path_from_steps(dirs, 0.05)
    assert M.turn_frames(path, 21, 90.0, tolerance=5.0) == 9
    assert M.turn_frames(path, 21, -90.0, tolerance=5.0) is None


def test_turn_frames_needs_the_heading_to_hold_and_the_body_to_move():
    # Passes through the target for two steps, leaves, then holds it from the 6th step.
    dirs = [0.0] * 5 + [90.0, 90.0, 0.0, 0.0, 0.0] + [90.0] * 6
    path = path_from_steps(dirs, 0.05)
    assert M.turn_frames(path, 6, 90.0) == 6
    # Standing still never reaches a heading, even one that atan2(0, 0) = 0° would give.
    still = torch.zeros(20, 3)
    assert M.turn_frames(still, 5, 0.0) is None


# Drift


def test_student_t_quantiles_match_the_tables():
    assert M.student_t_quantile(0.975, 10) == pytest.approx(2.228139, abs=1e-3)
    assert M.student_t_quantile(0.975, 100) == pytest.approx(1.983972, abs=1e-3)
    # One degree of freedom is Cauchy: tan(π (p - ½)).
    assert M.student_t_quantile(0.975, 1) == pytest.approx(math.tan(math.pi * 0.475), rel=1e-9)
    assert M.student_t_quantile(0.025, 10) == pytest.approx(-2.228139, abs=1e-3)
    assert M.student_t_cdf(0.0, 7) == 0.5


def test_drift_slope_of_an_exact_line():
    starts = torch.arange(0, 200, 16, dtype=torch.float32)
    d = M.drift_slope(0.25 + 0.003 * starts, starts)
    assert d["slope"] == pytest.approx(0.003, rel=1e-5)
    lo, hi = d["ci95"]
    assert hi - lo < 1e-6 and lo <= d["slope"] <= hi


def test_drift_slope_of_noise_has_zero_in_its_interval():
    starts = torch.arange(0, 640, 16, dtype=torch.float64)
    values = 0.1 + 0.01 * torch.randn(40, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    lo, hi = M.drift_slope(values, starts)["ci95"]
    assert lo < 0.0 < hi


def test_union_box_and_masked_scores_crop_to_both_foregrounds():
    from unica_train.metrics import masked_scores, union_box

    a = torch.zeros(64, 64, 4)
    b = torch.zeros(64, 64, 4)
    a[10:20, 30:40] = torch.tensor([0.5, 0.5, 0.5, 1.0])
    b[15:30, 35:45] = torch.tensor([0.5, 0.5, 0.5, 1.0])
    assert union_box(a[..., 3], b[..., 3]) == (10, 30, 30, 45)
    assert union_box(torch.zeros(4, 4), torch.zeros(4, 4)) is None
    # Identical images score infinity and 1 on either background.
    assert masked_scores(a, a, 0.0) == (float("inf"), 1.0)
    # Known answer: in the 20 × 15 box, a grey 0.5 (linear) square where the other image
    # is background. On black: (10·10 + 15·10 - 5·5 overlap) = 225 pixels differ by
    # srgb(0.5) on the part where only one image is grey; the overlap matches.
    g = 1.055 * 0.5 ** (1 / 2.4) - 0.055
    differing = 10 * 10 + 15 * 10 - 2 * 5 * 5
    mse = differing * g * g / (20 * 15)
    got, _ = masked_scores(a, b, 0.0)
    assert abs(got - (-10 * math.log10(mse))) < 1e-3
    # On white the grey differs from white by 1 - srgb(0.5).
    mse_white = differing * (1 - g) ** 2 / (20 * 15)
    got_white, _ = masked_scores(a, b, 1.0)
    assert abs(got_white - (-10 * math.log10(mse_white))) < 1e-3
    # Unmasked, the black background around would inflate PSNR: the masked score is lower.
    from unica_train.splats import psnr, srgb
    assert got < psnr(srgb(a[..., :3]), srgb(b[..., :3]))


def test_stop_frames_counts_frames_until_the_root_rests():
    from unica_train.metrics import stop_frames

    # 30 fps: moving 0.1 m a frame (3 m/s), released at frame 5, then slowing 3, 2, 1,
    # 0.03 m/s... : the speed is below 0.05 m/s from the 4th idle step on.
    steps = [0.1] * 5 + [0.1, 2 / 30, 1 / 30, 0.001, 0.001, 0.0]
    z = torch.tensor([0.0] + steps).cumsum(0)
    path = torch.stack([torch.zeros_like(z), torch.zeros_like(z), z], 1)
    frames, distance = stop_frames(path, 5, 30.0)
    assert frames == 3
    assert abs(distance - sum(steps[5:])) < 1e-6
    assert stop_frames(path[:9], 5, 30.0)[0] is None  # still moving at the end


def test_nearest_aligned_pose_undoes_a_turn():
    from unica_train.metrics import nearest_aligned_pose, rotate_y, yaw_align

    gen = torch.Generator().manual_seed(0)
    poses = torch.randn(5, 40, 3, generator=gen)
    frame = rotate_y(poses[3], -0.7)  # pose 3 turned away by 0.7 rad
    assert abs(float(yaw_align(frame, poses[3])) - 0.7) < 1e-5
    distance, index, theta = nearest_aligned_pose(frame, poses)
    assert index == 3 and abs(theta - 0.7) < 1e-5 and distance < 1e-5


def test_the_cfg_probe_measures_segments_and_prefers_the_right_heading():
    from unica_train.cfg_probe import score, segments

    # 2 frames toward +Z at 1 m a frame, then 2 toward +X at 0.5, then standing.
    path = [[0.0, 1, 0], [0, 1, 1], [0, 1, 2], [0.5, 1, 2], [1, 1, 2], [1, 1, 2]]
    got = segments(path, "2W 2A 1I")
    assert [s["key"] for s in got] == ["W", "A", "I"]
    assert abs(got[0]["heading_deg"]) < 1e-6 and abs(got[0]["distance_m"] - 2) < 1e-6
    assert abs(got[1]["heading_deg"] - 90) < 1e-6 and abs(got[1]["distance_m"] - 1) < 1e-6
    assert got[2]["distance_m"] == 0
    same = score(got, got)
    assert same == (0.0, True)
    wrong = [dict(s) for s in got]
    wrong[1]["heading_deg"] = 0.0  # went on forward under A
    wrong[0]["distance_m"] = 1.5
    error, heads = score(wrong, got)
    assert abs(error - 0.5) < 1e-6 and not heads
    glide = [dict(s) for s in got]
    glide[2]["distance_m"] = 0.3  # slid on 0.3 m after the release
    assert score(glide, got) == (0.3, True)


def test_report_names_the_pose_stride_in_words():
    from unica_train.report import every

    assert [every(n) for n in (1, 2, 3, 4, 11, 12, 21, 22, 23, 111)] == [
        "every", "every 2nd", "every 3rd", "every 4th", "every 11th", "every 12th", "every 21st", "every 22nd", "every 23rd",
        "every 111th"]


def test_the_cfg_probe_gives_the_evaluations_turns_stop_and_speed():
    from unica_train.cfg_probe import motion_line, motion_numbers

    # 20 frames of W at 0.08 m a frame (2.4 m/s), then A at once, then 10 frames of Idle
    # that stop after 2: 0.04 m, 0.01 m, then still.
    path = [[0.0, 1.0, 0.0]]
    for _ in range(20):
        path.append([path[-1][0], 1.0, path[-1][2] + 0.08])
    for _ in range(20):
        path.append([path[-1][0] + 0.08, 1.0, path[-1][2]])
    for step in [0.04, 0.01] + [0.0] * 8:
        path.append([path[-1][0] + step, 1.0, path[-1][2]])
    teacher = [list(p) for p in path]
    got = motion_numbers(path, teacher, "20W 20A 10I")
    assert got["turns"] == {"W→A (90°)": (1, 1)}  # the first A step already heads +X
    assert got["stop_frames"] == 2 and got["teacher_stop_frames"] == 2
    assert abs(got["stop_distance_m"] - 0.05) < 1e-6
    assert got["speed_error_pct"] == 0.0
    slow = [list(p) for p in path]
    for i in range(1, 21):  # W at 0.072 m a frame: 10 % slow
        slow[i][2] = 0.072 * i
    for i in range(21, len(slow)):
        slow[i][2] = 0.072 * 20
    assert abs(motion_numbers(slow, teacher, "20W 20A 10I")["speed_error_pct"] - 10.0) < 1e-3
    assert "stops after A 2/2 (0.05 m)" in motion_line(got)


def test_the_report_and_the_probe_name_the_braking():
    import pytest

    from unica_train.cfg_probe import brakes
    from unica_train.report import _idle_text

    base = {"cfg_scale": 4.7, "guide_idle": False, "idle_cfg_scale": 1.5}
    braked = dict(base, idle_brake_cfg_scale=2.0, idle_brake_frames=10)
    assert _idle_text(base) == " (Idle frames at CFG 1.5)"
    assert _idle_text(braked) == " (Idle frames at CFG 1.5, the first 10 after a key at CFG 2)"
    assert _idle_text(dict(braked, idle_cfg_scale=None)) == " (Idle frames unguided, the first 10 after a key at CFG 2)"
    assert _idle_text(dict(braked, idle_cfg_scale=None, guide_idle=True)) == (
        " (Idle frames as the keys, the first 10 after a key at CFG 2)")
    assert _idle_text(dict(braked, cfg_scale=1)) == ""
    assert _idle_text({"cfg_scale": 4.0}) == ""
    default = {"idle_brake_cfg_scale": None, "idle_brake_frames": 0}
    assert brakes(None, default) == [default]
    assert brakes("2:10,none", default) == [{"idle_brake_cfg_scale": 2.0, "idle_brake_frames": 10}, default]
    for bad in ("2", "2:0", "2:-1", "nan:10", "inf:3", "x:3"):
        with pytest.raises(SystemExit):
            brakes(bad, default)
