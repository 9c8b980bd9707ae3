"""The paper's ablation tables, computed with the evaluation protocol.

* Samplers (paper's Table 7): every sampler over a grid of step counts; per sampler, the fewest steps whose
  FID and top-3 R-precision are both within ``tol`` (5%) of that sampler's best, with those figures.
* Architectures (paper's Table 4): each preset trained the same number of steps on the same data, then
  evaluated the same way.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ..core.errors import SMFError
from ..motion.rigid import DEFAULT_FIT, RigidFitConfig
from .protocol import EvalConfig, evaluate

ARCH_PRESETS = ("unet-baseline", "unet-xattn", "unet-xattn-gn", "dit", "dit-xattn", "retnet", "retnet-xattn")
ARCH_LABELS = {"unet-baseline": "UNet baseline", "unet-xattn": "UNet + cross-attention",
               "unet-xattn-gn": "UNet + cross-attention + GroupNorm tweak", "dit": "DiT baseline",
               "dit-xattn": "DiT + cross-attention", "retnet": "RetNet baseline", "retnet-xattn": "RetNet + cross-attention"}


def min_steps_within(by_steps: dict[int, dict], tol: float = 0.05) -> dict:
    """``{steps: {"fid": (mean, ci), "top3": (mean, ci), ...}}`` -> the fewest steps whose FID <= best*(1+tol)
    and top-3 >= best*(1-tol): {"steps", "fid", "top3", "best_fid", "best_top3"}."""
    if not by_steps:
        raise SMFError("no step counts to compare")
    fid = {s: r["fid"][0] for s, r in by_steps.items()}
    top3 = {s: r["top3"][0] for s, r in by_steps.items()}
    best_fid, best_top3 = min(fid.values()), max(top3.values())
    ok = [s for s in sorted(by_steps) if fid[s] <= best_fid * (1 + tol) + 1e-12 and top3[s] >= best_top3 * (1 - tol)]
    s = ok[0] if ok else min(by_steps, key=lambda k: (fid[k] / max(best_fid, 1e-12), -top3[k]))
    return {"steps": s, "fid": by_steps[s]["fid"], "top3": by_steps[s]["top3"], "best_fid": best_fid,
            "best_top3": best_top3, "aits_seconds": by_steps[s].get("aits_seconds")}


def ablate_samplers(pipe, embedder, data, cfg: EvalConfig, grid: dict[str, list[int]], *, progress: bool = True,
                    log=print) -> dict:
    """Evaluate each sampler at each step count in ``grid``; returns {"runs": {sampler: {steps: row}},
    "table": {sampler: min_steps_within(...)}}."""
    runs: dict[str, dict[int, dict]] = {}
    for sampler, steps_list in grid.items():
        runs[sampler] = {}
        for steps in steps_list:
            res = evaluate(pipe, embedder, data, replace(cfg, sampler=sampler, steps=int(steps)), progress=progress)
            row = dict(res["rows"]["Generated"])
            row["aits_seconds"] = res.get("aits_seconds")
            runs[sampler][int(steps)] = row
            log(f"{sampler:28s} {steps:5d} steps: FID {row['fid'][0]:.3f}  top-3 {row['top3'][0]:.3f}  "
                f"AITS {row['aits_seconds'] * 1000:.0f} ms")
    return {"runs": runs, "table": {s: min_steps_within(r) for s, r in runs.items()}}


def sampler_markdown(result: dict, tol: float = 0.05) -> str:
    lines = [f"| Sampler | Min. steps within {tol:.0%} of best | FID ↓ | R-prec top-3 ↑ | best FID | best top-3 "
             "| AITS (ms) |", "|---|---|---|---|---|---|---|"]
    for s, row in result["table"].items():
        aits = row.get("aits_seconds")
        lines.append(f"| {s} | {row['steps']} | {row['fid'][0]:.3f} ± {row['fid'][1]:.3f} | {row['top3'][0]:.3f} ± "
                     f"{row['top3'][1]:.3f} | {row['best_fid']:.3f} | {row['best_top3']:.3f} | "
                     f"{'–' if aits is None else f'{aits * 1000:.0f}'} |")
    lines += ["", "All runs (steps: FID / top-3):", ""]
    for s, by in result["runs"].items():
        lines.append(f"- {s}: " + ", ".join(f"{k}: {v['fid'][0]:.3f} / {v['top3'][0]:.3f}" for k, v in sorted(by.items())))
    return "\n".join(lines)


def ablate_arch(data, out: Path, embedder, cfg: EvalConfig, presets, train_cfg, *, progress: bool = True,
                text_cache: Path | None = None, log=print, rigid: RigidFitConfig | None = DEFAULT_FIT) -> dict:
    """Train each preset with ``train_cfg`` (same steps, batch, seed) into ``out/<preset>`` (a finished run is
    reused), evaluate it with ``cfg`` (the pipeline's rigid stage ``rigid``); returns {preset: {"params", "train_seconds", "row"}}."""
    import csv
    import json

    from ..diffusion.checkpoint import CHECKPOINT_DIR, CONFIG
    from ..diffusion.train import train
    from ..pipelines.motion_pipeline import MotionPipeline

    table = {}
    for preset in presets:
        run = Path(out) / preset
        tcfg = replace(train_cfg, preset=preset)
        cfg_file = run / CHECKPOINT_DIR / CONFIG
        done = cfg_file.is_file() and json.loads(cfg_file.read_text()).get("step") == tcfg.steps
        if not done:
            train(data, run, tcfg, resume=cfg_file.is_file(), progress=progress, text_cache=text_cache)
        with open(run / "log.csv") as f:
            rows = list(csv.DictReader(f))
        seconds = float(rows[-1]["seconds"]) if rows else float("nan")
        pipe = MotionPipeline.from_pretrained(run, backend="torch", device="cpu", rigid=rigid)
        res = evaluate(pipe, embedder, data, cfg, progress=progress)
        params = sum(p.numel() for p in pipe.model.parameters())
        table[preset] = {"label": ARCH_LABELS.get(preset, preset), "params": params, "train_seconds": seconds,
                         "steps": tcfg.steps, "row": res["rows"]["Generated"], "aits_seconds": res.get("aits_seconds"),
                         "real": res["rows"]["Real motion"]}
        r = table[preset]["row"]
        log(f"{preset:16s} FID {r['fid'][0]:.3f}  top-3 {r['top3'][0]:.3f}  ({params / 1e6:.2f}M params)")
    return table


def arch_markdown(table: dict) -> str:
    keys = ("fid", "top1", "top2", "top3", "matching", "diversity")
    lines = ["| Architecture | Params | Train steps | FID ↓ | top-1 ↑ | top-2 ↑ | top-3 ↑ | Matching ↓ | Diversity → "
             "| AITS (ms) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, t in table.items():
        cells = [f"{t['row'][k][0]:.3f} ± {t['row'][k][1]:.3f}" for k in keys]
        aits = t.get("aits_seconds")
        lines.append(f"| {t['label']} | {t['params'] / 1e6:.2f}M | {t['steps']} | " + " | ".join(cells)
                     + f" | {'–' if aits is None else f'{aits * 1000:.0f}'} |")
    return "\n".join(lines)


__all__ = ["ARCH_PRESETS", "min_steps_within", "ablate_samplers", "sampler_markdown", "ablate_arch", "arch_markdown"]
