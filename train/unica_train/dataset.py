"""Baked datasets (written by `unica bake`): position maps materialised by linear blend
skinning of the reference mesh and the pixel -> surface gather, group normalisation
identical to the Rust one, and 4-frame training groups with their action labels."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file

FORMAT = "unica-dataset"
VERSION = 1
MAP_SIZE = 128
GROUP = 4
ANCHOR = 2  # the frame whose root is centred; its action drives frame 3 -> 4
ACTIONS = ["Idle", "Forward", "Backward", "Left", "Right"]
# Frames after a key change that count as "just after the switch" (stage-2 oversampling).
AFTER_SWITCH = 20
# The action a group's action becomes when the group is turned a quarter about +Y by
# `quarter_turn`: the keys move along fixed world directions (src/avatar/locomotion.rs:
# W +Z, S -Z, A +X, D -X), and a quarter turn takes +Z to +X, +X to -Z, -Z to -X, -X to +Z,
# so W becomes A, A becomes S, S becomes D and D becomes W; Idle stays Idle.
QUARTER_TURN_ACTION = (0, 3, 4, 2, 1)


def quarter_turn(points: torch.Tensor, turns: int = 1) -> torch.Tensor:
    """Points [..., 3] turned `turns` quarter turns about +Y: (x, y, z) -> (z, y, -x) each,
    which turns a heading θ (0 along +Z, 90° along +X) into θ + 90°. The teacher's motion
    is the same in every direction (gravity is vertical), so a turned group is a group she
    could have made facing another way; `QUARTER_TURN_ACTION` turns its label with it."""
    for _ in range(turns % 4):
        points = torch.stack([points[..., 2], points[..., 1], -points[..., 0]], -1)
    return points


def quarter_turn_action(action: int, turns: int = 1) -> int:
    """The action of a group turned `turns` quarter turns (`quarter_turn`)."""
    for _ in range(turns % 4):
        action = QUARTER_TURN_ACTION[action]
    return action


def action_quarter(action: int) -> int | None:
    """A movement key's direction as quarter turns (`quarter_turn`) from W's: W 0, A 1,
    S 2, D 3; None for Idle (the engine's `Action::quarter`)."""
    for q in range(4):
        if quarter_turn_action(1, q) == action:
            return q
    return None


class DatasetError(ValueError):
    """A dataset that cannot be used; the message names the file and the problem."""


def _check(path: Path, tensors: dict, name: str, shape: tuple, dtype: torch.dtype) -> torch.Tensor:
    if name not in tensors:
        raise DatasetError(f"{path}: tensor '{name}' is missing")
    t = tensors[name]
    if t.dtype != dtype:
        raise DatasetError(f"{path}: tensor '{name}' is {t.dtype}, expected {dtype}")
    if len(t.shape) != len(shape) or any(s is not None and s != f for s, f in zip(shape, t.shape)):
        raise DatasetError(f"{path}: tensor '{name}' has shape {list(t.shape)}, expected {list(shape)}")
    return t


@dataclass
class Group:
    clip: int
    start: int
    action: int
    after_switch: bool


class BakedDataset:
    """A baked dataset on the CPU; frames are materialised on demand."""

    def __init__(self, root: str | Path):
        self.dir = Path(root)
        manifest_path = self.dir / "manifest.json"
        try:
            self.manifest = json.loads(manifest_path.read_text())
        except (OSError, ValueError) as e:
            raise DatasetError(f"{manifest_path}: {e}") from e
        m = self.manifest
        if m.get("format") != FORMAT or m.get("version") != VERSION:
            raise DatasetError(f"{manifest_path}: format {m.get('format')} v{m.get('version')}, expected {FORMAT} v{VERSION}")
        ref_path = self.dir / "reference.safetensors"
        try:
            ref = load_file(str(ref_path))
        except Exception as e:  # safetensors raises several kinds
            raise DatasetError(f"{ref_path}: {e}") from e
        v, n = m["vertices"], m["foreground_pixels"]
        self.bind = _check(ref_path, ref, "bind_positions", (v, 3), torch.float32)
        self.joints = _check(ref_path, ref, "joints", (v, 4), torch.int32).long()
        self.weights = _check(ref_path, ref, "weights", (v, 4), torch.float32)
        self.colors = _check(ref_path, ref, "colors", (v, 3), torch.float32)
        self.triangles = _check(ref_path, ref, "triangles", (None, 3), torch.int32).long()
        self.pixels = _check(ref_path, ref, "pixels", (n,), torch.int32).long()
        self.pixel_triangles = _check(ref_path, ref, "pixel_triangles", (n,), torch.int32).long()
        self.barycentrics = _check(ref_path, ref, "barycentrics", (n, 3), torch.float32)
        self.waist = _check(ref_path, ref, "waist", (None,), torch.int32).long()
        self.scale = float(m["norm_scale"])
        self.bones = m["bones"]
        self.clips = []
        for info in m["clips"]:
            path = self.dir / info["file"]
            try:
                data = load_file(str(path))
            except Exception as e:
                raise DatasetError(f"{path}: {e}") from e
            f = info["frames"]
            self.clips.append({
                "skin": _check(path, data, "skin", (f, self.bones, 3, 4), torch.float32),
                "actions": _check(path, data, "actions", (f,), torch.int32).long(),
                "root": _check(path, data, "root", (f, 3), torch.float32),
                "switch": info["switch_frame"],
            })

    def positions(self, clip: int, frames) -> torch.Tensor:
        """World-space foreground points [F, N, 3]: LBS of the reference, then the gather."""
        skin = self.clips[clip]["skin"][frames]  # [F, B, 3, 4]
        if skin.dim() == 3:
            skin = skin[None]
        m = skin[:, self.joints]  # [F, V, 4, 3, 4]
        blended = (m * self.weights[None, :, :, None, None]).sum(2)  # [F, V, 3, 4]
        posed = torch.einsum("fvij,vj->fvi", blended[..., :3], self.bind) + blended[..., 3]
        corners = posed[:, self.triangles[self.pixel_triangles]]  # [F, N, 3, 3]
        return (corners * self.barycentrics[None, :, :, None]).sum(2)

    def pixel_colors(self) -> torch.Tensor:
        """Each foreground pixel's linear RGB: the reference's vertex colours interpolated at
        the pixel's surface point ([N, 3])."""
        corners = self.colors[self.triangles[self.pixel_triangles]]  # [N, 3, 3]
        return (corners * self.barycentrics[:, :, None]).sum(1)

    def root(self, points: torch.Tensor) -> torch.Tensor:
        """The root of each frame: the mean of its waist points ([..., N, 3] -> [..., 3])."""
        return points[..., self.waist, :].mean(-2)

    def normalise(self, group: torch.Tensor, anchor: int = ANCHOR):
        """A group [G, N, 3] to the unit cube with frame `anchor`'s root at 0.5."""
        root = self.root(group[anchor])
        unit = (group - root) * self.scale + 0.5
        if unit.min() < 0 or unit.max() > 1:
            raise DatasetError(f"{self.dir}: a normalised value leaves [0, 1] ({unit.min():.3f}, {unit.max():.3f})")
        return unit, root

    def to_maps(self, unit: torch.Tensor) -> torch.Tensor:
        """Foreground values [..., N, 3] -> maps [..., 3, 128, 128] with background 0."""
        lead = unit.shape[:-2]
        maps = torch.zeros(*lead, MAP_SIZE * MAP_SIZE, 3, dtype=unit.dtype)
        maps[..., self.pixels, :] = unit
        return maps.reshape(*lead, MAP_SIZE, MAP_SIZE, 3).movedim(-1, -3)

    def mask(self) -> torch.Tensor:
        """[1, 128, 128] foreground mask."""
        m = torch.zeros(MAP_SIZE * MAP_SIZE)
        m[self.pixels] = 1
        return m.reshape(1, MAP_SIZE, MAP_SIZE)

    def groups(self) -> list[Group]:
        """Every 4-frame window at stride 1; its label is the 3rd frame's action."""
        out = []
        for c, clip in enumerate(self.clips):
            frames = clip["actions"].shape[0]
            for start in range(frames - GROUP + 1):
                third = start + ANCHOR
                after = clip["switch"] <= third + 1 < clip["switch"] + AFTER_SWITCH and clip["switch"] < frames
                out.append(Group(c, start, int(clip["actions"][third]), bool(after)))
        return out
