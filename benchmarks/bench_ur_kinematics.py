"""Cost of the UR kinematics, as ratios to one forward-kinematics call in the same run.

Run: .venv/bin/python -m benchmarks.bench_ur_kinematics
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from lasercal_hw.ur_kinematics import forward_kinematics, inverse_kinematics, inverse_kinematics_all


def per_call_s(fn: Callable[[], object], repeats: int) -> float:
    """Best of three timings of ``repeats`` calls, per call."""
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        for _ in range(repeats):
            fn()
        best = min(best, (time.perf_counter() - start) / repeats)
    return best


def main() -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, 6)
    target = forward_kinematics(q)
    stack = rng.uniform(-np.pi, np.pi, (1000, 6))
    fk_s = per_call_s(lambda: forward_kinematics(q), 2000)
    fk_stack_s = per_call_s(lambda: forward_kinematics(stack), 20) / len(stack)
    ik_all_s = per_call_s(lambda: inverse_kinematics_all(target), 200)
    ik_near_s = per_call_s(lambda: inverse_kinematics(target, q), 200)
    print(f"reference: one forward_kinematics call = {fk_s * 1e6:.1f} us")
    print(f"forward_kinematics on a stack of 1000, per pose: {fk_stack_s / fk_s:.3f} x reference")
    print(f"inverse_kinematics_all (8 branches, FK-verified): {ik_all_s / fk_s:.1f} x reference")
    print(f"inverse_kinematics (nearest to q_near): {ik_near_s / fk_s:.1f} x reference")


if __name__ == "__main__":
    main()
