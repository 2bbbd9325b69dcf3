"""One validation for every parameter a request can send the viewer: types, ranges, caps and names.

Everything a request says passes through here before any file is opened or
any fit runs, and a bad value is a `BadRequest` (HTTP 400) naming the
parameter and the reason: nothing a request can say reaches the engine as a
wrong type or an unbounded amount of work.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import re
from typing import Any, get_type_hints

from fwcore.engine.config import PRESETS, DecompositionConfig

MAX_ECHOES = 200_000  # the most echoes one request returns, whatever the page asks
MAX_PULSE_LIST = 1000
MAX_NAME = 1024  # characters of a run id, input id or file name
PULSE_ID = re.compile(r"-?[0-9]{1,20}")
INT64 = (-(2 ** 63), 2 ** 63 - 1)


class BadRequest(ValueError):
    """A request's parameter is missing or wrong: the message names it and says why (HTTP 400)."""


def _try_settings() -> dict[str, tuple]:
    """The settings Try may change, from their declaration (fwcore.engine.config.setting's `refit`): a choice of
    the enum's values, a flag, or an int or float within the bounds that keep one refit within seconds."""
    kinds = get_type_hints(DecompositionConfig)
    found: dict[str, tuple] = {}
    for field in dataclasses.fields(DecompositionConfig):
        refit, kind = field.metadata.get("refit"), kinds[field.name]
        if not refit:
            continue
        if isinstance(kind, type) and issubclass(kind, enum.Enum):
            found[field.name] = ("choice", [m.value for m in kind])
        elif kind is bool:
            found[field.name] = ("bool",)
        else:
            found[field.name] = (kind.__name__, *refit)
    return found


TRY_SETTINGS: dict[str, tuple] = _try_settings()  # name -> ("choice", values) | ("bool",) | ("int"/"float", lo, hi)


def _number(name: str, value: Any, kind: str, lo: float, hi: float) -> int | float:
    # JSON true/false are Python ints: a flag is no number
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BadRequest(f"{name} must be a number, not {value!r}")
    if kind == "int" and not isinstance(value, int):
        raise BadRequest(f"{name} must be a whole number, not {value!r}")
    if not math.isfinite(value) or not lo <= value <= hi:
        raise BadRequest(f"{name} must lie in [{lo:g}, {hi:g}], not {value!r}")
    return value


def try_changes(changes: Any) -> dict[str, Any]:
    """The settings a refit changes, each checked against TRY_SETTINGS."""
    if changes is None:
        return {}
    if not isinstance(changes, dict):
        raise BadRequest("changes must be an object of decomposition settings")
    out = {}
    for name, value in changes.items():
        spec = TRY_SETTINGS.get(name)
        if spec is None:
            raise BadRequest(f"{name!r} cannot be changed in a refit; these can: {', '.join(TRY_SETTINGS)}")
        if spec[0] == "choice":
            if value not in spec[1]:
                raise BadRequest(f"{name} must be one of {', '.join(spec[1])}, not {value!r}")
        elif spec[0] == "bool":
            if not isinstance(value, bool):
                raise BadRequest(f"{name} must be true or false, not {value!r}")
        else:
            value = _number(name, value, *spec)
        out[name] = value
    return out


def preset(value: Any) -> str | None:
    if value in (None, ""):
        return None
    if not isinstance(value, str) or value not in PRESETS:
        raise BadRequest(f"preset must be one of {', '.join(sorted(PRESETS))}, not {value!r}")
    return value


def name(value: Any, what: str) -> str:
    """A run id, input id or file name: a non-empty string of printable characters, bounded."""
    if not isinstance(value, str) or value == "":
        raise BadRequest(f"missing parameter {what!r}" if value in (None, "") else f"{what} must be a string")
    if len(value) > MAX_NAME or any(ord(c) < 32 for c in value):
        raise BadRequest(f"{what} must be at most {MAX_NAME} printable characters")
    return value


def pulse_id(value: Any) -> int:
    """A pulse id: a whole number (JSON) or its digits (a URL), within int64."""
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise BadRequest(f"pulse must be a whole number, not {value!r}")
    if isinstance(value, str) and not PULSE_ID.fullmatch(value.strip()):
        raise BadRequest(f"pulse must be a whole number, not {value!r}")
    number = int(value)
    if not INT64[0] <= number <= INT64[1]:
        raise BadRequest(f"pulse must fit a 64-bit integer, not {value!r}")
    return number


def query_value(params: dict[str, list[str]], key: str, default: str | None = None) -> str:
    """One query parameter's value (its first); missing without a default is a bad request."""
    values = params.get(key)
    if not values or values[0] == "":
        if default is None:
            raise BadRequest(f"missing parameter {key!r}")
        return default
    return values[0]


def limit(params: dict[str, list[str]], default: int, cap: int = MAX_ECHOES) -> int:
    text = query_value(params, "limit", str(default))
    if not re.fullmatch(r"[0-9]{1,9}", text):
        raise BadRequest(f"limit must be a whole number in [0, {cap}], not {text!r}")
    return min(int(text), cap)


def box(params: dict[str, list[str]]) -> tuple[float, float, float, float] | None:
    """xmin,xmax,ymin,ymax in the map's frame, finite and ordered; None for the whole run."""
    text = query_value(params, "box", "")
    if text == "":
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise BadRequest(f"box must be four numbers xmin,xmax,ymin,ymax, not {text!r}") from None
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise BadRequest(f"box must be four finite numbers xmin,xmax,ymin,ymax, not {text!r}")
    if values[0] > values[1] or values[2] > values[3]:
        raise BadRequest(f"box must have xmin <= xmax and ymin <= ymax, not {text!r}")
    return values


def choice(params: dict[str, list[str]], key: str, allowed, default: str) -> str:
    value = query_value(params, key, default)
    if value not in allowed:
        raise BadRequest(f"{key} must be one of {', '.join(allowed)}, not {value!r}")
    return value


def flag(params: dict[str, list[str]], key: str) -> bool:
    return choice(params, key, ("0", "1"), "0") == "1"


def page(value: Any) -> str | None:
    """The page's own id (a random token it makes): a later refit from it cancels its waiting one."""
    if value in (None, ""):
        return None
    if not isinstance(value, str) or not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", value):
        raise BadRequest("page must be up to 64 letters, digits, _ or -")
    return value
