"""Argument checks shared by every stage. Each raises :class:`~semslam.errors.InputError` (or the
subclass given) with the argument's name, what was expected and what was given."""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import InputError, SemslamError


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def as_float_array(
    name: str,
    value: Any,
    shape: tuple[int | None, ...],
    *,
    caller: str = "",
    finite: bool = True,
    dtype: type = np.float64,
    error: type[SemslamError] = InputError,
) -> np.ndarray:
    """Return ``value`` as a C-contiguous float array of the given shape (``None`` = any length).

    Raises ``error`` naming ``name`` when the shape does not match or, with ``finite``, when a value
    is NaN or infinite.
    """
    where = f" of {caller}" if caller else ""
    try:
        arr = np.ascontiguousarray(value, dtype=dtype)
    except (TypeError, ValueError):
        raise error(
            f"The {name!r} argument{where} must be a numeric array of shape {_shape_text(shape)}. "
            f"Got {_describe(value)} instead."
        ) from None
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        raise error(
            f"The {name!r} argument{where} must have shape {_shape_text(shape)}. "
            f"Got {arr.shape} instead."
        )
    if finite and arr.size and not np.isfinite(arr).all():
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise error(
            f"The {name!r} argument{where} must be finite. Got {bad} NaN or infinite value(s) instead."
        )
    return arr


def _shape_text(shape: tuple[int | None, ...]) -> str:
    letters = iter("NMKL")
    parts = [str(s) if s is not None else next(letters) for s in shape]
    return "(" + ", ".join(parts) + (",)" if len(parts) == 1 else ")")


def check_positive(name: str, value: Any, *, caller: str = "", allow_zero: bool = False) -> float:
    """Return ``value`` as a float; raise if it is not a finite number > 0 (>= 0 with allow_zero)."""
    where = f" of {caller}" if caller else ""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"The {name!r} argument{where} must be a number. Got {_describe(value)} instead.") from None
    ok = np.isfinite(v) and (v >= 0 if allow_zero else v > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"The {name!r} argument{where} must be a finite number {bound}. Got {value!r} instead.")
    return v


def check_int(name: str, value: Any, *, caller: str = "", minimum: int | None = None,
              maximum: int | None = None) -> int:
    """Return ``value`` as an int within [minimum, maximum]; raise otherwise."""
    where = f" of {caller}" if caller else ""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"The {name!r} argument{where} must be an integer. Got {_describe(value)} instead.")
    v = int(value)
    if (minimum is not None and v < minimum) or (maximum is not None and v > maximum):
        lo = "-inf" if minimum is None else minimum
        hi = "inf" if maximum is None else maximum
        raise InputError(f"The {name!r} argument{where} must be in [{lo}, {hi}]. Got {v} instead.")
    return v


def check_choice(name: str, value: Any, choices: tuple[str, ...] | list[str], *, caller: str = "") -> str:
    """Return ``value`` if it is one of ``choices``; raise otherwise."""
    where = f" of {caller}" if caller else ""
    if value not in choices:
        raise InputError(
            f"The {name!r} argument{where} must be one of {', '.join(map(repr, choices))}. Got {value!r} instead."
        )
    return value


def as_rng(seed: "int | np.random.Generator | None", *, caller: str = "") -> np.random.Generator:
    """A numpy Generator from a seed (int), an existing Generator, or None (fresh entropy)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0):
        return np.random.default_rng(seed)
    where = f" of {caller}" if caller else ""
    raise InputError(
        f"The 'seed' argument{where} must be a non-negative integer or a numpy Generator. Got {_describe(seed)} "
        f"instead."
    )
