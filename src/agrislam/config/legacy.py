"""Configs written for the layout before `advanced:` keep reading: a key that moved is
taken from its old place with a warning naming the new one; a knob that became a constant
is ignored with a warning."""

from __future__ import annotations

import warnings
from typing import Any

from pydantic import BaseModel

# knobs that are module constants now, with where they live
REMOVED_KEYS = {
    ("association", "index_margin"): "mapping/index_upkeep.py",
    ("association", "index_rebuild_steps"): "mapping/index_upkeep.py",
    ("association", "index_sweep_steps"): "mapping/index_upkeep.py",
    ("slam", "covariance_reuse_steps"): "backend/incremental",
    ("slam", "turn_refine_max_factors"): "backend/incremental",
    ("checkpoint", "frames_per_mb"): "run/checkpoint.py",
}


def moved_to_advanced(
    data: Any, sections: dict[str, type[BaseModel]], advanced: dict[str, type[BaseModel]]
) -> Any:
    """`data` (a config as read from a file) with every key of the old layout in its new
    place: a whole section that is advanced now (`semantics`, `maintenance`, `season`) under
    `advanced`, and a key of a main section that only its advanced part has likewise."""
    if not isinstance(data, dict):
        return data
    data = dict(data)
    moved: dict[str, dict[str, Any]] = {}
    for name in advanced:
        section = data.get(name)
        if name not in sections and name in data:
            _warn(name, f"advanced.{name}")
            moved[name] = data.pop(name)
        elif isinstance(section, dict):
            kept = {}
            for key, value in section.items():
                if (name, key) in REMOVED_KEYS:
                    warnings.warn(
                        f"{name}.{key} is ignored: it is a constant now "
                        f"({REMOVED_KEYS[name, key]})",
                        FutureWarning,
                        stacklevel=4,
                    )
                elif key in sections[name].model_fields or key not in _fields(advanced[name]):
                    kept[key] = value
                else:  # an older name still taken is warned of where it is renamed
                    if key in advanced[name].model_fields:
                        _warn(f"{name}.{key}", f"advanced.{name}.{key}")
                    moved.setdefault(name, {})[key] = value
            data[name] = kept
    for (name, key), where in REMOVED_KEYS.items():
        section = data.get(name)
        if name not in advanced and isinstance(section, dict) and key in section:
            warnings.warn(
                f"{name}.{key} is ignored: it is a constant now ({where})", FutureWarning, 4
            )
            data[name] = {k: v for k, v in section.items() if k != key}
    if moved:
        into = data.get("advanced")
        into = dict(into) if isinstance(into, dict) else {}
        for name, values in moved.items():
            into[name] = (
                {**values, **(into.get(name) or {})} if isinstance(values, dict) else values
            )
        data["advanced"] = into
    return data


def _fields(model: type[BaseModel]) -> set[str]:
    """A section's keys, with those its validators still take under an older name."""
    renamed = getattr(model, "LEGACY_KEYS", ())
    return set(model.model_fields) | set(renamed)


def _warn(old: str, new: str) -> None:
    warnings.warn(f"{old} is now {new}; please move it", FutureWarning, stacklevel=5)
