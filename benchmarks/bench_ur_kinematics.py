"""Cost of the UR kinematics, as ratios to one forward-kinematics call in the same run.

Run: .venv/bin/python -m benchmarks.bench_ur_kinematics
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from lasercal_hw.models import RobotCalibration
from lasercal_hw.ur_kinematics import (
    UR5E,
    forward_kinematics,
    inverse_kinematics,
    inverse_kinematics_all,
    inverse_kinematics_branches,
    model_from_robot_calibration,
)

#: A factory calibration's size: corrections of about this much (m, rad) on every DH row.
CORRECTION_SPREAD = 3e-4


def calibrated_ur5e(rng: np.random.Generator) -> RobotCalibration:
    """A UR5e with its own rows: the published table plus corrections of ``CORRECTION_SPREAD``."""
    def off(values: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(float(v) for v in np.asarray(values) + rng.normal(0.0, CORRECTION_SPREAD, 6))

    return RobotCalibration(
        checksums=(1, 2, 3, 4, 5, 6), dh_theta_rad=off((0.0,) * 6), dh_a_m=off(UR5E.dh.a_m),
        dh_d_m=off(UR5E.dh.d_m), dh_alpha_rad=off(UR5E.dh.alpha_rad), calibration_status=0,
        model="UR5e", software_version="5.11.6.108949",
    )


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
    own = model_from_robot_calibration(calibrated_ur5e(rng))
    targets = forward_kinematics(stack, model=own)
    published_s = per_call_s(lambda: inverse_kinematics_branches(targets, model=UR5E), 3) / len(stack)
    own_s = per_call_s(lambda: inverse_kinematics_branches(targets, model=own), 3) / len(stack)
    found = np.isfinite(inverse_kinematics_branches(targets, model=own)).all(axis=-1).sum(axis=1).mean()
    spread = f"+-{CORRECTION_SPREAD * 1e3:.1f} mm/mrad"
    print(f"inverse_kinematics_branches on 1000 poses, per pose: published UR5e table "
          f"{published_s / fk_s:.1f} x reference; the robot's own rows ({spread}, refined) "
          f"{own_s / fk_s:.1f} x reference = {own_s / published_s:.1f} x the published table's, "
          f"{found:.2f} branches per pose")


if __name__ == "__main__":
    main()
