"""What a moved scanner does to a twist drill's centres in the verify (docs/verify.md, step 5).

Where the calibration's flute phase pass was kept, the verify takes each plain fit's section
offset out at the calibration's transform (``run.flute_phase.FluteShift.moved``). A moved
scanner's plane cuts the bit elsewhere along its helix and sees another face of the section,
so its centre holds ``offset(moved transform) - offset(calibration's)`` beside the crossing's
own move. The drift test models that change as linear in the move ``x = (dt, e)`` (its
parameters, applied to the pass's transform as to the calibration's): ``flute_jacobian``, by
central differences at the calibration. The section's offsets jump where a flute's edge meets a
land, so the step is a third of the moves a verify looks for, and the change is not followed
exactly: the exact change in the Gauss-Newton estimate (tried) put the estimate's error within
2 std for 75 % of components against 93 % with this (drill job, seed 103, 12 turns of 0.3 deg).
"""

from __future__ import annotations

import numpy as np

from lasercal_hw.geometry import make_transform, rotvec_to_matrix
from lasercal_hw.models import FloatArray
from lasercal_hw.run.flute_phase import FluteShift

#: Central-difference steps of the Jacobian: shift (m) and turn (rad), a third of the moves
#: the verify's benchmarks apply (3 mm, 0.3 deg).
STEP_SHIFT_M = 0.001
STEP_TURN_RAD = float(np.radians(0.1))


def moved_transform(T_base_laser: FloatArray, x: FloatArray) -> FloatArray:
    """``T_base_laser`` moved by ``x = (dt m, e rad about base axes)``, as the drift test moves it."""
    T = np.asarray(T_base_laser, dtype=float)
    return make_transform(rotvec_to_matrix(x[3:]) @ T[:3, :3], T[:3, 3] + x[:3])


def flute_jacobian(flutes: FluteShift, tcp_poses: FloatArray) -> FloatArray:
    """The section offsets' change (N, 2, 6), m per unit of ``x``, at the calibration: the
    offsets ``flutes`` takes out at the moved transform less those at its own."""
    steps = np.diag([STEP_SHIFT_M] * 3 + [STEP_TURN_RAD] * 3)
    columns = [
        (
            flutes.offsets_m(tcp_poses, moved_transform(flutes.T_base_laser, step))
            - flutes.offsets_m(tcp_poses, moved_transform(flutes.T_base_laser, -step))
        )
        / (2.0 * step.sum())
        for step in steps
    ]
    return np.stack(columns, axis=-1)
