"""What a moved scanner does to a twist drill's centres in the verify (docs/verify.md, steps 5-6).

Where the calibration's flute phase pass was kept, the verify takes each plain fit's section
offset out at the calibration's transform (``run.flute_phase.FluteShift.moved``). A moved
scanner's plane cuts the bit elsewhere along its helix and sees another face of the section,
so its centre holds ``offset(moved transform) - offset(calibration's)`` beside the crossing's
own move. The drift test models that change as linear in the move ``x = (dt, e)`` (its
parameters, applied to the pass's transform as to the calibration's), by differences at the
calibration (``HelixChange``). The section's offsets jump where a flute's edge meets a land, so
the step is a third of the moves a verify looks for, the change is not followed exactly (the
exact change in the Gauss-Newton estimate, tried: its error within 2 std for 74-75 % of
components against 93-97 % linearised, drill job, seeds 103 and 105, 12 turns of 0.3 deg at 10
scans), and a jump counts for the power only on the side it lies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lasercal_hw.geometry import make_transform, rotvec_to_matrix
from lasercal_hw.models import FloatArray
from lasercal_hw.run.flute_phase import FluteShift

#: Difference steps: shift (m) and turn (rad), a third of the moves the verify's benchmarks
#: apply (3 mm, 0.3 deg).
STEP_SHIFT_M = 0.001
STEP_TURN_RAD = float(np.radians(0.1))


def moved_transform(T_base_laser: FloatArray, x: FloatArray) -> FloatArray:
    """``T_base_laser`` moved by ``x = (dt m, e rad about base axes)``, as the drift test moves it."""
    T = np.asarray(T_base_laser, dtype=float)
    return make_transform(rotvec_to_matrix(x[3:]) @ T[:3, :3], T[:3, 3] + x[:3])


def offset_change_m(flutes: FluteShift, tcp_poses: FloatArray, x: FloatArray) -> FloatArray:
    """The section offsets' change (N, 2), m, at each pose when the scanner moves by ``x``: the
    offsets ``flutes`` takes out at the moved transform less those at its own."""
    moved = flutes.offsets_m(tcp_poses, moved_transform(flutes.T_base_laser, x))
    return moved - flutes.offsets_m(tcp_poses)


@dataclass(frozen=True)
class HelixChange:
    """The section offsets' change (N, 2, 6 each, m per unit of ``x``) for a move along each
    parameter: ``forward`` for a positive one, ``backward`` for a negative one."""

    forward: FloatArray
    backward: FloatArray

    @property
    def jacobian(self) -> FloatArray:
        """The central difference: the change's model in the estimate."""
        return 0.5 * (self.forward + self.backward)

    @classmethod
    def of(cls, flutes: FluteShift, tcp_poses: FloatArray) -> HelixChange:
        """The offsets ``flutes`` takes out at each moved transform less those at its own."""
        steps = np.diag([STEP_SHIFT_M] * 3 + [STEP_TURN_RAD] * 3)

        def change(step: FloatArray) -> FloatArray:
            return offset_change_m(flutes, tcp_poses, step) / float(np.abs(step).sum())

        forward = np.stack([change(step) for step in steps], axis=-1)
        backward = np.stack([-change(-step) for step in steps], axis=-1)
        return cls(forward, backward)

    @classmethod
    def none(cls, waypoints: int) -> HelixChange:
        """No flutes: no change."""
        zeros = np.zeros((waypoints, 2, 6))
        return cls(zeros, zeros)
