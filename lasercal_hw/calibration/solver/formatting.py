"""Small helpers that put numbers into messages and the result: a direction in words, finite floats, lists."""

from __future__ import annotations

import numpy as np

from lasercal_hw.geometry import FloatArray


def _fmt(vector: FloatArray) -> str:
    names = ("x", "y", "z")
    axis = int(np.argmax(np.abs(vector)))
    if abs(vector[axis]) > 0.98:
        return f"{'-' if vector[axis] < 0 else ''}{names[axis]}"
    return "(" + ", ".join(f"{v:+.2f}" for v in vector) + ")"


def _finite(value: float) -> float:
    return float(value) if np.isfinite(value) else 1e12


def _list(array: FloatArray) -> list[float]:
    return [float(v) for v in np.asarray(array).ravel()]
