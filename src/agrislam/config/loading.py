"""Reading a configuration file: YAML, TOML or JSON, chosen by its extension."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import yaml


def load_mapping(path: str | Path) -> dict[str, Any]:
    """Read a YAML, TOML or JSON file into a dict, choosing the parser by extension."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    suffix = path.suffix.lower()
    parsers = {".toml": tomllib.loads, ".json": json.loads, ".yaml": yaml.safe_load}
    parse = parsers.get(".yaml" if suffix == ".yml" else suffix)
    if parse is None:
        raise ValueError(f"{path}: unknown config format {suffix!r} (use .yaml, .toml or .json)")
    try:
        data = parse(text)
    except (ValueError, yaml.YAMLError) as err:  # TOML and JSON errors are ValueErrors
        where = getattr(err, "problem_mark", None)
        at = f" at line {where.line + 1}, column {where.column + 1}" if where else ""
        what = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"{path}: not valid {suffix[1:].upper()}{at}: {what}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top level")
    return data


def merged(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    """`base` with `extra` written over it, section by section (a config's overrides)."""
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merged(out[key], value)
        else:
            out[key] = value
    return out
