"""Dotted configuration keys: listing them, the nearest to a misspelt one, and validation
errors that name the key, the file and what was expected."""

from __future__ import annotations

import difflib
import math
from typing import Any

from pydantic import BaseModel, ValidationError


def leaf_keys(model: BaseModel, prefix: str = "") -> list[str]:
    """Every dotted leaf key of a model, e.g. `lidar.rate_hz`."""

    def walk(p: str, node: Any) -> list[str]:
        if isinstance(node, dict) and node:
            out: list[str] = []
            for k, v in node.items():
                out += walk(f"{p}.{k}" if p else k, v)
            return out
        return [p]

    return walk(prefix.rstrip("."), model.model_dump(mode="json"))


def settings_dump(model: BaseModel, exclude_unset: bool = False) -> dict:
    """A settings model as JSON-ready values that validate back to the same model: an infinite
    or NaN setting (a range without limit) as the text "inf", "-inf" or "nan", which strict
    JSON has no number for (a null would not validate back)."""
    return _non_finite_as_text(model.model_dump(mode="json", exclude_unset=exclude_unset))


def _non_finite_as_text(o: Any) -> Any:
    if isinstance(o, dict):
        return {k: _non_finite_as_text(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_non_finite_as_text(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return str(o)
    return o


def nearest_keys(key: str, keys: list[str]) -> str:
    close = difflib.get_close_matches(key, keys, n=5, cutoff=0.5)
    if not close:  # fall back on keys sharing the last component
        leaf = key.rsplit(".", 1)[-1]
        close = [k for k in keys if k.rsplit(".", 1)[-1] == leaf][:5]
    return ", ".join(close) if close else "(none close; `boomtip scenarios --keys` lists all)"


def format_validation(err: ValidationError, source: str, prefix: str = "", keys: list[str] | None = None,
                      overridden: dict[str, str] | None = None) -> str:
    """One line per error: the source, the full dotted key and what was wrong; an unknown key
    gets the nearest valid ones. `prefix` is prepended to the model's own keys
    (`installation.`); `overridden` maps keys set by `--set` to the text that set them."""
    keys = keys or []
    lines = []
    for e in err.errors():
        key = prefix + ".".join(str(p) for p in e["loc"])
        got = e.get("input")
        by_set = next((k for k in overridden or {} if key == k or key.startswith(k + ".")), None)
        if by_set is not None:  # the user's --set, not the file, supplied this value
            lines.append(f"--set {overridden[by_set]}: key '{key}': {e['msg']} (got {got!r})")
        elif e["type"] == "extra_forbidden":
            lines.append(f"{source}: unknown key '{key}'; nearest valid keys: {nearest_keys(key, keys)}")
        else:
            got_s = "" if isinstance(got, (dict, list)) else f" (got {got!r})"
            lines.append(f"{source}: key '{key or '<root>'}': {e['msg']}{got_s}")
    return "\n".join(lines)
