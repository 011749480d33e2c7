"""Typed, validated hyper-parameters for filters, scenarios, noise schedules and outlier models.

Every tunable thing in navlab is a frozen dataclass whose fields are declared with :func:`param`.
The metadata (range, help text, choices) drives validation here, the CLI's ``--config`` file and the
app's widgets, so a value is checked in exactly one place.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from navlab.errors import NavlabError

#: Largest base seed, in the CLI, a configuration and the app alike: the largest whole number a
#: browser holds exactly (2**53 − 1; a link's number and the app's number inputs are JavaScript
#: numbers). numpy's SeedSequence takes any non-negative integer, so every seed in range works.
SEED_MAX = 2**53 - 1
#: Most epochs of a run, in the CLI, a configuration and the app alike (scenario parameters
#: named ``epochs`` are capped by it too).
MAX_EPOCHS = 200_000


def param(
    default: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    help: str = "",
    choices: tuple[Any, ...] | None = None,
    ui: bool = True,
    tune: tuple[float, float] | None = None,
) -> Any:
    """Declare a parameter field with its admissible range and a help text.

    Parameters
    ----------
    default : Any
        Default value (a number, bool, str or a tuple of numbers).
    lo, hi : float, optional
        Inclusive bounds for numbers.
    help : str
        One line shown in the CLI listing and as the app's tooltip.
    choices : tuple, optional
        Allowed values for strings.
    ui : bool
        Whether the app offers a widget for it (tuples and rarely used options say False).
    tune : (float, float), optional
        Marks a hyper-parameter that fair tuning (:mod:`navlab.tune`) searches, and the range it
        searches: inside [lo, hi], usually much narrower (an admissible γ ∈ [0.1, 1e12] is a
        validity limit, not a search range). None: not tuned.
    """
    if tune is not None:
        t_lo, t_hi = tune
        if not t_lo < t_hi or (lo is not None and t_lo < lo) or (hi is not None and t_hi > hi):
            raise ValueError(f"tune range {tune} must be increasing and inside [{lo}, {hi}]")
    meta = {"lo": lo, "hi": hi, "help": help, "choices": choices, "ui": ui, "tune": tune}
    if isinstance(default, (list, dict)):
        raise TypeError("use tuples for sequence defaults")
    return dataclasses.field(default=default, metadata=meta)


def _check_value(owner: str, name: str, value: Any, default: Any, meta: Mapping[str, Any]) -> Any:
    where = f"{owner}: parameter '{name}'"
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise NavlabError(f"{where} must be true or false, got {value!r}")
        return value
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise NavlabError(f"{where} must be a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise NavlabError(f"{where} must be a finite number, got {value!r}")
        if isinstance(default, int) and not isinstance(default, bool):
            if float(value) != int(value):
                raise NavlabError(f"{where} must be a whole number, got {value!r}")
            value = int(value)
        else:
            value = float(value)
        lo, hi = meta.get("lo"), meta.get("hi")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise NavlabError(f"{where} = {value} is outside [{lo}, {hi}]; choose a value in range")
        return value
    if isinstance(default, str) or (default is None and meta.get("choices")):
        if not isinstance(value, str):
            raise NavlabError(f"{where} must be text, got {value!r}")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise NavlabError(f"{where} = {value!r} is not one of {', '.join(map(str, choices))}")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)):
            raise NavlabError(f"{where} must be a list, got {value!r}")
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise NavlabError(f"{where} must be a list of finite numbers, got {value!r}")
            out.append(v)
        return tuple(out)
    return value


def build(cls: type, values: Mapping[str, Any] | None, owner: str) -> Any:
    """Instantiate the parameter dataclass ``cls`` from a mapping, validating every value.

    Raises
    ------
    NavlabError
        For an unknown name or a value of the wrong type or out of range.
    """
    values = dict(values or {})
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        known = ", ".join(sorted(fields)) or "(none)"
        raise NavlabError(f"{owner}: unknown parameter(s) {', '.join(unknown)}; known: {known}")
    kwargs = {}
    for name, value in values.items():
        f = fields[name]
        kwargs[name] = _check_value(owner, name, value, f.default, f.metadata)
    return cls(**kwargs)


def describe(cls: type) -> list[dict[str, Any]]:
    """List the parameters of ``cls`` as dicts (name, default, lo, hi, help, choices, ui, tune)."""
    out = []
    for f in dataclasses.fields(cls):
        d = {"name": f.name, "default": f.default}
        d.update({k: f.metadata.get(k) for k in ("lo", "hi", "help", "choices", "ui", "tune")})
        out.append(d)
    return out


def as_dict(obj: Any) -> dict[str, Any]:
    """Plain-dict form of a parameter dataclass (tuples become lists, for JSON)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(obj).items()}


@dataclasses.dataclass(frozen=True)
class NoParams:
    """For things that take no parameters."""
