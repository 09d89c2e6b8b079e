"""The season figure: the change map of the latest survey (plants kept, new,
gone, and how much each grew) and growth curves of a sample of plants over the surveys."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

SAMPLE = 12  # plants whose growth curves are drawn


def growth_attribute(schema) -> str | None:
    """The attribute the growth curves show: the first with a time model (App. B), else
    the first continuous one, else one named like a size; None without a schema."""
    if schema is None:
        return None
    attributes = schema.attributes
    timed = [n for n, a in attributes.items() if getattr(a, "time_model", None) is not None]
    continuous = list(schema.continuous)
    sizes = [n for n in attributes if "size" in n or "length" in n]
    return next(iter(timed + continuous + sizes), None)


def _value(beliefs: dict, name: str) -> float:
    v = beliefs[name]
    if len(v) == 2 and not np.isclose(sum(v), 1.0):
        return float(v[0])
    return float(np.dot(np.arange(len(v)), v))  # expected cell of a discrete size


def write_season_figure(history, path: str | Path, attribute: str | None = None) -> Path:
    """Change map (left) and growth curves (right) as one PNG, from a `history.History`
    (surveys and plant rows; not imported: a sink imports no other sink)."""
    path = Path(path)
    latest = history.surveys[-1][0]
    t0 = history.surveys[0][1]
    days = {s: (t - t0) / 86_400.0 for s, t, _, _ in history.surveys}
    rows = history.rows
    name = attribute
    by_plant: dict[int, list[tuple[float, float]]] = {}
    for r in rows:
        if name is not None and r[2] != "gone":
            by_plant.setdefault(r[0], []).append((days[r[1]], _value(json.loads(r[11]), name)))
    now = [r for r in rows if r[1] == latest]
    fig, (ax_map, ax_growth) = plt.subplots(1, 2, figsize=(14, 6))
    styles = {
        "seen": dict(c="0.6", s=10, marker="o"),
        "not_looked_at": dict(c="0.85", s=8, marker="o"),
        "new": dict(c="tab:green", s=40, marker="^"),
        "unconfirmed": dict(c="tab:orange", s=14, marker="."),
        "gone": dict(c="tab:red", s=50, marker="x"),
    }
    grew = {p: v[-1][1] - v[-2][1] for p, v in by_plant.items() if len(v) > 1}
    for status, style in styles.items():
        pts = np.array([(r[3], r[4]) for r in now if r[2] == status]).reshape(-1, 2)
        label = f"{status.replace('_', ' ')} ({len(pts)})"
        if status == "seen" and grew:
            g = np.array([grew.get(r[0], 0.0) for r in now if r[2] == status])
            sc = ax_map.scatter(pts[:, 0], pts[:, 1], c=g, cmap="viridis", s=12, label=label)
            fig.colorbar(sc, ax=ax_map, label=f"{name} grown since the last survey")
        else:
            ax_map.scatter(pts[:, 0], pts[:, 1], label=label, **style)
    ax_map.set_aspect("equal")
    ax_map.set_title(f"changes in survey {latest} (day {days[latest]:.0f})")
    ax_map.set_xlabel("x (m)")
    ax_map.set_ylabel("y (m)")
    ax_map.legend(loc="upper right", fontsize=8)
    long_lived = sorted(p for p, v in by_plant.items() if len(v) == len(history.surveys))
    sample = long_lived[:: max(1, len(long_lived) // SAMPLE)][:SAMPLE]
    for p in sample:
        d, v = np.array(by_plant[p]).T
        ax_growth.plot(d, v, marker="o", label=f"plant {p}")
    ax_growth.set_xlabel("day of the season")
    ax_growth.set_ylabel(f"{name} (belief mean)" if name else "")
    ax_growth.set_title(f"growth of {len(sample)} plants seen in every survey")
    if sample:
        ax_growth.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=90, format="png")
    plt.close(fig)
    return path
