"""The evaluation report (unica_train.eval's results) as report.md with PNG plots: turn
curves, the drift plot, per-metric bars of the ablations and a contact sheet of generated
vs teacher frames. The paper's numbers stand beside ours where it has them."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from . import checkpoint as checkpoint_file  # noqa: E402
from . import metrics  # noqa: E402

PAPER_TURNS = {"180": (13.4, 12), "90": (9.8, 9)}


def _turn_plot(path: Path, results: dict) -> None:
    seq = results["sequence"]
    # Unwrapped, so a heading near ±180° does not jump across the plot.
    gen = np.degrees(np.unwrap(np.radians(metrics.headings(torch.tensor(seq["path"])).numpy())))
    fig, ax = plt.subplots(figsize=(8, 3.2))
    ax.plot(gen, label="generated", lw=1.2)
    if "teacher_headings" in seq:
        ax.plot(np.degrees(np.unwrap(np.radians(seq["teacher_headings"]))), label="teacher", lw=1.2)
    ax.set_xlabel("frame")
    ax.set_ylabel("direction of movement (°)")
    ax.set_title(f"direction of movement under {results['keys']}")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)


def _drift_plot(path: Path, long: dict) -> None:
    starts, values = np.array(long["starts"]), np.array(long["fvd_pca"])
    slope = long["slope_per_1000_frames"] / 1000
    intercept = values.mean() - slope * starts.mean()
    fig, ax = plt.subplots(figsize=(8, 3.2))
    ax.plot(starts, values, "o-", label=f"{long['window']}-frame windows")
    ax.plot(starts, intercept + slope * starts, "--",
            label=f"fit: {long['slope_per_1000_frames']:+.3f} per 1000 frames "
                  f"(95 % {long['ci95_per_1000_frames'][0]:+.3f} … {long['ci95_per_1000_frames'][1]:+.3f})")
    ax.set_xlabel("first frame of the window")
    ax.set_ylabel("Fréchet distance (PCA windows)")
    ax.set_title(f"long run: {long['frames']} frames")
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def _label(setting: dict, defaults: dict) -> str:
    """What a setting changes from the defaults; a variant of the teacher's DDIM sampler
    where the defaults run the one-pass student names its steps and scale."""
    teacher = defaults.get("one_pass") and not setting.get("one_pass")
    changed = [f"{k}={v}" for k, v in setting.items()
               if k != "one_pass" and (defaults.get(k) != v or (teacher and k in ("steps", "cfg_scale")))]
    label = ", ".join(changed) or "defaults"
    return f"teacher {label}" if teacher else label


def _bars(path: Path, results: dict) -> None:
    rows = results["ablations"]
    labels = [_label(r["setting"], results["defaults"]) for r in rows]
    panels = [("chamfer_mm", "Chamfer to nearest pose (mm)"), ("fvd_pca", "Fréchet distance (PCA windows)"),
              ("ms_per_frame", "PyTorch CPU ms per frame")]
    fig, axes = plt.subplots(1, len(panels), figsize=(12, 3.6))
    for ax, (key, title) in zip(axes, panels):
        ax.barh(labels, [r[key] for r in rows])
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def _sheet(path: Path, pairs: list) -> None:
    if not pairs:
        return
    rows = [np.concatenate([w.numpy(), g.numpy()], 1) for w, g in pairs]
    buffer = io.BytesIO()
    plt.imsave(buffer, np.clip(np.concatenate(rows, 0), 0, 1), format="png")
    checkpoint_file.write_file_atomic(Path(path), buffer.getvalue())


def save_figure(fig, path) -> None:
    """A figure as a PNG written whole or not at all."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    checkpoint_file.write_file_atomic(Path(path), buffer.getvalue())


def every(n: int) -> str:
    """'every frame', 'every 2nd frame', 'every 3rd', 'every 4th' … (without the noun)."""
    if n == 1:
        return "every"
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"every {n}{suffix}"


def _fmt(v, digits=1):
    return "—" if v is None else f"{v:.{digits}f}"


def _masked_section(results: dict, data: str) -> list[str]:
    """The issue #17 numbers (summary.json) as a section of the report."""
    from .eval import DEFAULT_RENDER_EVERY, summary

    m, sm = results["masked"], summary(results)
    tf, fr = m["teacher_forced"], m["free_running"]
    mo = m["motion"]
    path = "the shipped engine path (WGSL model and PCA clean-up)" if m["free_running_path"] == "engine" else \
        "the PyTorch reference of the live loop (no `--engine` rollout was given)"
    lines = [
        "## Masked images, free-running geometry, stopping (`summary.json`)",
        "",
        f"Images of {tf['size']}² px from the 4 cardinal views, splats at the {results['image']['level']}² level with the "
        "refiner, scored on a black and on a white background only inside the union of both images' foreground "
        "bounding boxes (the empty background around the figure cannot pad the score).",
        "",
        f"- Teacher-forced: {tf['frames']} held-out frames, each from its 3 ground-truth context frames and the true "
        "action. The ground-truth row draws the teacher's own geometry the same way (appearance alone).",
        f"- Free-running: the rollout of `{results['keys']}` through {path}; every {fr['every']}th frame "
        f"({fr['frames']} frames) is compared with the nearest of the dataset's {fr['rendered_poses']} rendered "
        f"teacher poses ({_render_density(fr.get('render_every', DEFAULT_RENDER_EVERY))}; both root-centred, the frame turned to the "
        "pose's best yaw, found by Chamfer), drawn in that pose's place and seen from its cameras (mean Chamfer to it "
        f"{fr['nearest_chamfer_mm']:.1f} mm).",
    ]
    tfr = m.get("teacher_free_running")
    if tfr:
        lines.append(f"- The free-running row's teacher reference: {tfr['frames']} of the teacher's own frames (after "
                     "their clips' key change), each matched the same way to the nearest rendered pose of the other "
                     f"clips and drawn there the same way (mean Chamfer to it {tfr['nearest_chamfer_mm']:.1f} mm). The "
                     "table's clips share whole segments and repeat the same strides, so where every frame is rendered "
                     "most teacher frames find their very pose in another clip and score as the ground-truth row; "
                     "where only some are, it shows what the render set's gaps cost.")
    lines += [
        "",
        "| images | PSNR black (dB) | SSIM black | PSNR white (dB) | SSIM white |",
        "| --- | --- | --- | --- | --- |",
    ]
    rows = [("teacher-forced, generated", tf["generated"]), ("teacher-forced, ground truth", tf["ground_truth"]),
            ("free-running, nearest pose", fr)]
    if tfr:
        rows.append(("free-running, the teacher's own frames", tfr))
    for name, row in rows:
        lines.append(f"| {name} | {row['black']['psnr']:.2f} | {row['black']['ssim']:.4f} | {row['white']['psnr']:.2f} | "
                     f"{row['white']['ssim']:.4f} |")
    lines += [
        "",
        "![masked contact sheet](contact_sheet_masked.png)",
        "",
        "(teacher-forced frames, all four views: teacher render left, generated refined splats right)",
        "",
        f"- Chamfer of {every(m['chamfer_every'])} free-running frame to the nearest dataset pose (root-centred, yaw-aligned): "
        f"**{sm['chamfer_mm']:.1f} mm** (the teacher's own frames, each against the other clips' poses: "
        f"{sm['teacher_chamfer_mm']:.1f} mm; {m['poses']} poses, {every(m.get('pose_stride', 2))} dataset frame).",
        f"- Fréchet stand-in **{sm['fvd_pca']:.3f}**; the dataset against itself (even against odd clips): "
        f"{sm['dataset_fvd_pca']:.3f}.",
        f"- Stop: the keys are released at frame {mo['release_frame']}; the root is below 0.05 m/s for good after "
        f"**{_fmt(mo['stop_frames'], 0)} frames** (teacher {_fmt(mo['teacher_stop_frames'], 0)}) and travels "
        f"{mo['stop_distance_m']:.2f} m after the release (teacher {mo['teacher_stop_distance_m']:.2f} m).",
        "",
        f"- Speeds and headings: each key's frames after its first {results.get('settle', 15)} (keys {results['keys']}).",
        "",
        "| key | speed (m/s) | teacher | error | heading (°) | teacher |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for s in mo["segments"]:
        lines.append(f"| {s['key']} | {s['speed']:.2f} | {s['teacher_speed']:.2f} | {s['speed_error_pct']:.1f} % | "
                     f"{s['heading']:.1f} | {s['teacher_heading']:.1f} |")
    lines += ["", "| turn | frames | teacher |", "| --- | --- | --- |"]
    for t in mo["turns"]:
        lines.append(f"| {t['turn']} | {_fmt(t['generated'], 0)} | {_fmt(t['teacher'], 0)} |")
    by_seed = m.get("motion_by_seed", [])
    if by_seed:
        names = [t["turn"] for t in by_seed[0]["turns"]]
        stops_keys = by_seed[0].get("stops_keys")
        lines += ["", f"The PyTorch loop from {len(by_seed)} seeds (one seed can be lucky; summary.json's `seeds_*` keys are "
                  f"the worst of them): turns and speeds on `{results['keys']}`, and the stop after every release"
                  + (f" of `{stops_keys}` and of that script" if stops_keys else "") + ":", "",
                  "| seed | " + " | ".join(names) + " | worst speed error |", "| --- |" + " --- |" * (len(names) + 1)]
        for r in by_seed:
            turns = " | ".join(f"{_fmt(t['generated'], 0)} ({_fmt(t['teacher'], 0)})" for t in r["turns"])
            worst = max(s["speed_error_pct"] for s in r["segments"])
            lines.append(f"| {r['seed']} | {turns} | {worst:.1f} % |")
        releases = [f"after {st['after']} (frame {st['release_frame']})" for st in by_seed[0].get("stops", [])]
        if releases:
            lines += ["", "| seed | " + " | ".join(releases) + " |", "| --- |" + " --- |" * len(releases)]
            for r in by_seed:
                frames = lambda n: "never" if n is None else f"{n} fr"
                cells = " | ".join(f"{frames(st['frames'])}, {st['distance_m']:.2f} m ({frames(st['teacher_frames'])}, "
                                   f"{st['teacher_distance_m']:.2f} m)" for st in r["stops"])
                lines.append(f"| {r['seed']} | {cells} |")
        lines += ["", "(the teacher's in brackets; a stop is the frames until the root stays below 0.05 m/s, never where it "
                  "is still moving when the next key is pressed, and the distance travelled after the release)"]
        phase = [r for r in by_seed if r.get("phase_turns")]
        if phase:
            turns = phase[0]["phase_turns"]
            lines += ["", f"Turns pressed at many phases of the stride: `{phase[0]['turns_keys']}` (every key held a different "
                      "number of frames; summary.json's `phase_turn180_frames` and `phase_turn90_frames` are the slowest "
                      "against the teacher's, over every seed):", "",
                      "| seed | " + " | ".join(f"{t['turn']} at {t['frame']}" for t in turns) + " |",
                      "| --- |" + " --- |" * len(turns)]
            for r in phase:
                lines.append(f"| {r['seed']} | " + " | ".join(f"{_fmt(t['generated'], 0)} ({_fmt(t['teacher'], 0)})"
                                                              for t in r["phase_turns"]) + " |")
    render_every = fr.get("render_every", DEFAULT_RENDER_EVERY)
    option = "" if render_every == DEFAULT_RENDER_EVERY else f" --render-every {render_every}"
    lines += ["", f"The dataset is rebuilt with `unica bake <the character> --out {data}{option}` (the character file "
              "is in the dataset's manifest).", ""]
    return lines


def _render_density(every: int) -> str:
    """How densely the dataset's poses are rendered, for the free-running sentence."""
    if every == 1:
        return "every frame"
    return (f"every {every}th frame only: most frames are then a few frames of the stride from the nearest, which "
            "costs even the teacher's own frames much of their score; `unica bake --render-every 1` renders every pose")


def _idle_text(d: dict) -> str:
    """How Idle frames are guided, for the sampler line ('' where as the keys)."""
    if d.get("cfg_scale") == 1:
        return ""  # an unguided sampler: Idle frames too
    brake, frames = d.get("idle_brake_cfg_scale"), d.get("idle_brake_frames", 0)
    brakes = brake is not None and frames > 0
    braking = f", the first {frames} after a key at CFG {brake:g}" if brakes else ""
    if d.get("idle_cfg_scale") is not None:
        return f" (Idle frames at CFG {d['idle_cfg_scale']:g}{braking})"
    if not d.get("guide_idle", True):
        return f" (Idle frames unguided{braking})"
    return f" (Idle frames as the keys{braking})" if braking else ""


def write_report(out: Path, results: dict, sheet: list, masked_sheet: list | None = None) -> None:
    _turn_plot(out / "turns.png", results)
    _drift_plot(out / "drift.png", results["long_run"])
    _bars(out / "ablations.png", results)
    _sheet(out / "contact_sheet.png", sheet)
    if masked_sheet:
        _sheet(out / "contact_sheet_masked.png", masked_sheet)
    img, seq, long = results["image"], results["sequence"], results["long_run"]
    d = results["defaults"]
    lines = [
        "# Evaluation report",
        "",
        f"Bundle `{results['bundle']}`, dataset `{results['data']}`, key script `{results['keys']}`, seed {results['seed']}"
        f"{' (quick mode: a short script, fewer frames)' if results['quick'] else ''}. Sampler: {d['steps']} DDIM steps, "
        f"CFG {d['cfg_scale']}{_idle_text(d)}, starting noise × "
        f"{d.get('noise_scale', 1.0):g}, PCA on. Written by `unica eval` in {results['minutes']:.1f} min.",
        "",
        *(_masked_section(results, results["data"]) if "masked" in results else []),
        "## Image level",
        "",
        f"{img['frames']} frames of held-out clips {', '.join(map(str, img.get('clips', [])))} × 4 cardinal views ({img['views']} images, {img['size']}² px, black background), "
        f"splats at the {img['level']}² level against the teacher's renders. Each frame is generated from its three "
        "ground-truth context frames and the true action; the ground-truth rows draw the teacher's own geometry and so "
        "measure appearance alone.",
        "",
        "| geometry, splats | PSNR (dB) | SSIM |",
        "| --- | --- | --- |",
    ]
    for name, m in img["metrics"].items():
        lines.append(f"| {name} | {m['psnr']:.2f} | {m['ssim']:.4f} |")
    lines += [
        "",
        "The paper reports LPIPS and FVD; both need pretrained networks that cannot be had here, so they are not "
        "reported. SSIM stands in for the perceptual metric and the Fréchet distance below for FVD.",
        "",
        "![contact sheet](contact_sheet.png)",
        "",
        "(teacher render left, generated and refined splats right, front views)",
        "",
        "## Sequence level",
        "",
        f"- Geometry error to the nearest teacher pose in the dataset (Chamfer, root-centred): **{seq['chamfer_mm']:.1f} mm** "
        "mean over frames.",
        f"- Fréchet distance between 16-frame windows of the {8} leading PCA coefficients, generated vs the dataset's "
        f"(our FVD stand-in): **{seq['fvd_pca']:.3f}**.",
        f"- PyTorch on this CPU: {seq['ms_per_frame']:.0f} ms per generated frame.",
        "",
        "| key | speed (m/s) | teacher | heading (°) | teacher |",
        "| --- | --- | --- | --- | --- |",
    ]
    for s in seq["segments"]:
        lines.append(f"| {s['key']} | {_fmt(s['speed'], 2)} | {_fmt(s['teacher_speed'], 2)} | {_fmt(s['heading'])} | "
                     f"{_fmt(s['teacher_heading'])} |")
    lines += ["", "Responsiveness: frames after the key change until the direction of movement is within 10° of the new "
              "key's and stays there (as the paper measures):", "",
              "| turn | generated | teacher | paper (model / its ground truth) |", "| --- | --- | --- | --- |"]
    for label, t in seq["turns"].items():
        paper = next((f"{m} / {g}" for k, (m, g) in PAPER_TURNS.items() if f"({k}°)" in label), "—")
        lines.append(f"| {label} | {_fmt(t['generated'], 0)} | {_fmt(t['teacher'], 0)} | {paper} |")
    lines += ["", "![turns](turns.png)", "", "## Long run", "",
              f"{long['frames']} frames (the script repeated), {'all finite' if long['finite'] else 'NON-FINITE values'}. "
              f"Fréchet distance of each {long['window']}-frame window (stride {long['stride']}) against the dataset's; "
              f"fitted slope **{long['slope_per_1000_frames']:+.3f} per 1000 frames**, 95 % interval "
              f"{long['ci95_per_1000_frames'][0]:+.3f} … {long['ci95_per_1000_frames'][1]:+.3f} "
              f"({'no upward drift' if long['ci95_per_1000_frames'][0] <= 0 else 'an upward drift'}).",
              "", "![drift](drift.png)", "", "## Ablations", "",
              "| setting | Chamfer (mm) | Fréchet (PCA) | W speed | W heading | ms/frame |",
              "| --- | --- | --- | --- | --- | --- |"]
    for r in results["ablations"]:
        w = next((s for s in r["segments"] if s["key"] == "W"), None)
        lines.append(f"| {_label(r['setting'], d)} | {r['chamfer_mm']:.1f} | {r['fvd_pca']:.3f} | "
                     f"{_fmt(w and w['speed'], 2)} | {_fmt(w and w['heading'])} | {r['ms_per_frame']:.0f} |")
    lines += ["", "The refiner's ablation is the image table above (base vs refined).", "", "![ablations](ablations.png)", ""]
    checkpoint_file.write_text(out / "report.md", "\n".join(lines))
