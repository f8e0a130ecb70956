"""Numbers that come in from outside, checked before they are used: a finite real, and a value
cut short for an error message (a hostile number may have thousands of digits)."""

from __future__ import annotations

import math
from numbers import Real
from typing import Any

from sdfserver.errors import InvalidInput


def short(value: Any) -> str:
    """``value`` for an error message, at most about 60 characters."""
    text = repr(value)
    return text if len(text) <= 60 else text[:40] + f"... ({len(text)} characters)"


def finite(value: Any, where: str, error: type[InvalidInput] = InvalidInput) -> float:
    """``value`` as a finite float; ``error`` for anything else, an integer too large for a
    float included (``float()`` would raise OverflowError on it)."""
    kind = type(value)
    if kind is float:  # the common case, without the ABC check
        if value - value == 0.0:  # neither inf nor NaN
            return value
        raise error(f"{where} must be a finite number, got {short(value)}")
    if isinstance(value, bool) or not isinstance(value, Real):
        raise error(f"{where} must be a finite number, got {short(value)}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise error(f"{where} must be a finite number, got {short(value)}")
    return number
