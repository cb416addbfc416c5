"""Reading several runs of a bench together (noise seeds, ``--from-results``): their saved
scene records, the label of a scene run and the statistics of paired ratios, shared by
``stereo_budget.py``, ``stereo_lines_gain.py`` and ``stereo_envelope.py``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def load_runs(paths, keep, bench: str, lacking: str) -> list[tuple[Path, list[dict]]]:
    """Each path (a ``results.json`` of a bench run, or the folder holding one) with its scene
    records that ``keep(record)`` accepts. A path without a ``results.json``, or whose records
    ``keep`` all refuses, is an error that names it (``"<bench>: <file> has <lacking>"``)."""
    runs = []
    for p in map(Path, paths):
        f = p / "results.json" if p.is_dir() else p
        if not f.is_file():
            raise SystemExit(f"{bench}: no results.json at {p}")
        rows = [r for r in json.loads(f.read_text()) if keep(r)]
        if not rows:
            raise SystemExit(f"{bench}: {f} has {lacking}")
        runs.append((p, rows))
    return runs


def scene_label(scene: dict) -> str:
    """``"<name> s<seed>"`` of a bench's scene record (seed 0 when the record has none)."""
    return f"{scene['name']} s{scene.get('seed', 0)}"


def ratio_stats(log_ratios, digits: int | None = None) -> dict:
    """Of ``(n,)`` logs of paired ratios ``a / b``: their geometric mean, the standard deviation
    of the logs (a fraction: the scatter one run's comparison is drawn from; 0 for one run) and
    how many are below 1 (``a`` lower). ``digits``: round the two floats."""
    lr = np.asarray(log_ratios, float)
    gm = float(np.exp(lr.mean()))
    sd = float(lr.std(ddof=1)) if len(lr) > 1 else 0.0
    if digits is not None:
        gm, sd = round(gm, digits), round(sd, digits)
    return {"geometric_mean_ratio": gm, "sd_log": sd, "lower": int((lr < 0).sum())}
