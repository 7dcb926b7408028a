"""The fake cell's default scene geometry as tests of trajectories see it."""

from __future__ import annotations

import numpy as np

from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform

# Default scene of the fake cell and the paper's ground truth: translation (0.30, 0.50,
# 0.20) m, ZYX (yaw, pitch, roll) = (5, 7, 3) deg.
T_BASE_LASER = make_transform(euler_zyx_to_matrix(*np.deg2rad([5.0, 7.0, 3.0])), [0.30, 0.50, 0.20])
FOV_HALF_RAD = np.deg2rad(135.0)
