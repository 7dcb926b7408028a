"""The fake cell: a fake UR controller and one fake UTM-30LX-EW per scene scanner on one
loopback address, sharing one simulated world (``fakes.world``), so every scanner sees the
rod wherever the fake robot holds it.

Both fakes run in this process (the robot's servers and cycle as threads, the scanner's
server as a thread); clients must run in another process (ur_rtde holds the GIL). When
ready, one line goes to standard output::

    fake cell ready: {"robot_host": ..., "scanner_url": ..., "T_base_laser": [[...]],
                      "scanners": {"front": {"scanner_url": ..., "T_base_laser": ...}, ...}, ...}

(``scanner_url`` and ``T_base_laser``: the first scanner's, as for a one-scanner scene.)

A dry run starts the cell as a child process (``fakes.cell_process``, which runs
``python -m fakes.cell``), reads that line and compares its result with ``T_base_laser``,
the world's ground truth. ``lasercal fake cell`` serves the same cell in the foreground.

Scene faults acted on here (a run first moves to its retract pose for the background,
then to waypoint 0, 1, ...):

* ``protective_stop_at_waypoint = k`` stops the robot halfway through move ``k + 2``;
* ``scanner_drop_at_waypoint = k`` drops the first scanner's connection once,
  ``SCANNER_DROP_DELAY_S`` after move ``k + 2`` has ended (during that waypoint's dwell);
* ``corrupt_checksum_every_scans = N`` corrupts a data-line checksum in every N-th scan;
* ``scanner_stale_field = "AFRT=560"`` changes that VV/PP/II value but not its checksum.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from fakes.scene import RobotKinematicsSettings, load_scene, with_model_override
from fakes.scip_faults import ScipFaults
from fakes.scip_identity import identity_of_scanner
from fakes.scip_server import DEFAULT_PORT, FakeScannerServer
from fakes.serving import serve_until_signal
from fakes.ur_controller.controller import ControllerConfig, FaultPlan
from fakes.ur_controller.kinematics_calibration import KinematicsCalibration
from fakes.ur_controller.process import FakeRobot
from fakes.world import World, WorldRangeSource
from lasercal_hw.errors import LasercalError
from lasercal_hw.models import FloatArray

READY_PREFIX = "fake cell ready:"
MOVES_BEFORE_FIRST_WAYPOINT = 1
SCANNER_DROP_DELAY_S = 0.3


def _kinematics(settings: RobotKinematicsSettings) -> KinematicsCalibration:
    """The scene's robot calibration as the fake controller holds it."""
    return KinematicsCalibration(
        checksums=tuple(settings.checksums), delta_theta_rad=tuple(settings.delta_theta_rad),
        delta_a_m=tuple(settings.delta_a_m), delta_d_m=tuple(settings.delta_d_m),
        delta_alpha_rad=tuple(settings.delta_alpha_rad),
    )


class FakeCell:
    """A fake robot and one fake scanner per scene scanner on ``address``, all looking at one
    world: the first scanner serves on ``DEFAULT_PORT``, the next on the ports after it."""

    def __init__(self, address: str, scene: Path | None = None, seed: int = 0) -> None:
        full_scene = with_model_override(load_scene(scene))
        self.worlds = {name: World(full_scene, name) for name in full_scene.scanner_names()}
        self.world = next(iter(self.worlds.values()))
        faults = self.world.scene.faults
        stop_at = faults.protective_stop_at_waypoint
        config = ControllerConfig(
            faults=FaultPlan(
                protective_stop_at_move=None if stop_at is None else stop_at + 1 + MOVES_BEFORE_FIRST_WAYPOINT
            ),
            kinematics=_kinematics(self.world.scene.robot_kinematics),
        )
        self.robot = FakeRobot(address, config)
        self.scanners = {
            name: FakeScannerServer(
                address, DEFAULT_PORT + index,
                source=WorldRangeSource(world, self._tcp_pose_at, seed + index),
                identity=identity_of_scanner(name),
                faults=ScipFaults(
                    corrupt_every_scans=faults.corrupt_checksum_every_scans,
                    stale_field=faults.scanner_stale_field,
                ),
            )
            for index, (name, world) in enumerate(self.worlds.items())
        }
        self.scanner = next(iter(self.scanners.values()))
        self.address = self.robot.address
        self.scanner_urls: dict[str, str] = {}
        drop_at = faults.scanner_drop_at_waypoint
        self._drop_after_moves = None if drop_at is None else drop_at + 1 + MOVES_BEFORE_FIRST_WAYPOINT
        self._drop_due_s: float | None = None
        if self._drop_after_moves is not None:
            self.robot.controller.add_tick_listener(self._maybe_drop_scanner)

    @property
    def scanner_url(self) -> str:
        """The first scanner's URL ("" before ``start``)."""
        return next(iter(self.scanner_urls.values()), "")

    def _maybe_drop_scanner(self, _snapshot: object) -> None:
        """On the controller's cycle: drop the scanner link once, shortly after the move to
        the configured waypoint has ended."""
        if self._drop_after_moves is None:
            return
        if self._drop_due_s is None:
            if self.robot.controller.moves_completed >= self._drop_after_moves:
                self._drop_due_s = time.monotonic() + SCANNER_DROP_DELAY_S
        elif time.monotonic() >= self._drop_due_s:
            self._drop_after_moves = None
            self.scanner.drop_connection()

    def _tcp_pose_at(self, time_s: float) -> FloatArray:
        """The TCP pose the fake controller reports now (scans are cast as they start)."""
        return self.robot.controller.tcp_pose_matrix()

    def start(self) -> None:
        """Bind every port and start serving; closes what was opened on failure."""
        try:
            self.robot.start()
            for name, server in self.scanners.items():
                self.scanner_urls[name] = server.start()
        except BaseException:
            self.close()
            raise

    def ready_document(self) -> dict[str, Any]:
        """What the ready line announces."""
        rod = self.world.rod
        return {
            "robot_host": self.address,
            "scanner_url": self.scanner_url,
            "T_base_laser": self.world.ground_truth_T_base_laser.tolist(),
            "rod": {
                "origin_m": np.asarray(rod.origin_m).tolist(),
                "direction": np.asarray(rod.direction).tolist(),
                "radius_m": rod.radius_m,
                "length_m": rod.length_m,
            },
            "scanners": {
                name: {"scanner_url": self.scanner_urls.get(name, ""),
                       "T_base_laser": world.ground_truth_T_base_laser.tolist()}
                for name, world in self.worlds.items()
            },
            "pid": os.getpid(),
        }

    def ready_line(self) -> str:
        """The single line announcing readiness."""
        return f"{READY_PREFIX} {json.dumps(self.ready_document())}"

    def close(self) -> None:
        """Stop both fakes; safe to call twice."""
        for server in self.scanners.values():
            server.stop()
        self.robot.close()


def main(argv: list[str] | None = None) -> None:
    """``python -m fakes.cell --address A [--scene FILE] [--seed N] [--lifeline-stdin]``: the
    child a ``FakeCellProcess`` starts (``lasercal fake cell`` is the same for people)."""
    parser = argparse.ArgumentParser(prog="python -m fakes.cell", description=main.__doc__)
    parser.add_argument("--address", required=True, help="loopback address to serve on")
    parser.add_argument("--scene", type=Path, default=None, help="scene file (TOML)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scanner's noise")
    parser.add_argument("--lifeline-stdin", action="store_true", help="stop when standard input closes")
    args = parser.parse_args(argv)
    try:
        cell = FakeCell(args.address, args.scene, args.seed)
        serve_until_signal(cell, sys.stdin.buffer if args.lifeline_stdin else None)
    except LasercalError as exc:  # a bad scene or a taken address: one line, for the parent to show
        sys.exit(f"fake cell: {exc}")


if __name__ == "__main__":
    main()
