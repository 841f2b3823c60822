"""Strict JSON for what the commands print and write: RFC 8259 has no NaN or Infinity, so a non-finite number
(a diverged run's RMS, an open interval's bound) becomes null, and numpy values become plain numbers and lists."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np


def strict(x: Any) -> Any:
    """``x`` with every non-finite float replaced by None and numpy arrays and scalars made plain Python."""
    if isinstance(x, np.ndarray):
        return strict(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {k: strict(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [strict(v) for v in x]
    return x


def dumps(x: Any, **kwargs: Any) -> str:
    """``json.dumps`` of :func:`strict` (``x``); raises ValueError rather than write a non-finite number."""
    return json.dumps(strict(x), allow_nan=False, **kwargs)
