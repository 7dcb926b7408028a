"""Design the waypoints for one cell: minimise the Cramér-Rao bound of the calibration over
candidates that keep every rule a run checks (``trajectories.candidates``).

The objective is the root of the sum of the pose's six variances (base axes), each in units
of the job's quality gate squared: the expected squared norm of the pose's error, which a
percentile of the error's norm follows (the largest std alone left the other axes free).
When the job estimates the rod's axis (``rod.estimate_axis``), the four axis parameters join
the information and the std are those of the pose with the axis unknown; the tool then also
turns widely about the rod (``AXIS_TOOL_TURN_SPREAD_DEG``), the motion that tells the axis
offset from the scanner's position. When the job estimates the scanner's range error
(``scanner.estimate_range_offset``), the terms of its curve over distance (offset, scale,
smooth term) join too: the design then spreads the crossings over distances and bearings
that tell the curve from the pose.
The Fisher information of a set of waypoints is the sum of theirs, so the search
works on per-candidate k x k blocks: a greedy pass adds the candidate that lowers the
objective most, exchange passes swap a chosen waypoint for a better one until none helps, and
a restart from each half of that choice looks past what single swaps can reach.
Chosen crossings keep ``MIN_SEPARATION_M`` apart (the robot's error is smooth, so neighbours would not add
independent information). The visiting order is a nearest-neighbour tour in joint space
from the waypoint nearest the start posture (UR's home unless given), improved by 2-opt,
then walked with the nearest IK solution: every step must stay on the design's branch (that
of the home posture) and below ``MAX_JOINT_STEP_RAD`` on every joint.

The information model (``lasercal_hw.calibration.model.extended_fisher_information``) is passed in,
as the IK is to ``trajectories.checks``: this package depends only on the ground of
``lasercal_hw``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from lasercal_hw.config import JobConfig
from lasercal_hw.geometry import FloatArray, matrix_to_pose
from lasercal_hw.models import RodLine
from lasercal_hw.ur_kinematics import URModel, inverse_kinematics
from trajectories.candidates import (
    AXIS_TOOL_TURN_SPREAD_DEG,
    DEFAULT_UNCERTAINTY,
    HOME_Q_RAD,
    TOOL_TURN_SPREAD_DEG,
    CandidatePool,
    CellRules,
    PoseUncertainty,
    draw_candidates,
    home_branch,
)
from trajectories.plane_crossing import rod_plane_crossings
from trajectories.waypoint import Waypoint


class InformationModel(Protocol):
    """Fisher information (k, k) of (translation, rotation about base axes[, rod axis offset (2),
    tilt (2)][, range error curve terms]) of the rod held at ``tcp_transforms`` (n, 4, 4) for a
    scanner at (rotation, translation_m)."""

    def __call__(
        self,
        rotation: FloatArray,
        translation_m: FloatArray,
        tcp_transforms: FloatArray,
        rod: RodLine,
        covariance_uv_m2: FloatArray,
        robot_sigma_m: float,
        *,
        with_axis: bool,
        with_offset: int = 0,
    ) -> FloatArray: ...



#: ``on_progress(stage, fraction)`` while the design runs.
ProgressCallback = Callable[[str, float], None]

#: Least distance between the crossings of two chosen waypoints (m).
MIN_SEPARATION_M = 0.05
#: Largest joint move between consecutive waypoints (rad), on every joint.
MAX_JOINT_STEP_RAD = 1.6
#: Joint distance within which a candidate counts as linked to a chosen one (rad).
LINK_STEP_RAD = 0.8 * MAX_JOINT_STEP_RAD
#: Exchange passes after the greedy pass.
EXCHANGE_PASSES = 3
#: Scan period of the UTM-30LX-EW (s): the scans a dwell averages.
SCAN_PERIOD_S = 0.025
#: Rounds of "drop the waypoint that breaks the walk and choose again".
_WALK_ROUNDS = 12
#: Pose parameters (the rest of an information matrix are the rod axis's and the range curve's).
POSE_PARAMETERS = 6
#: Range error curve terms a job that estimates the range error is designed for: offset and
#: slope over ln d (the solver adds higher terms only where the waypoints pin them down anyway).
DESIGN_RANGE_TERMS = 2
_AXES = [f"translation along base {a}" for a in "xyz"] + [f"rotation about base {a}" for a in "xyz"]


@dataclass(frozen=True)
class NoiseModel:
    """Noise the CRB assumes: the robot's position error per axis and the centre noise,
    ``centre_sigma_m`` for a rod of ``reference_radius_m`` at ``reference_range_m`` after
    ``reference_scans`` scans, growing with the square root of range / radius / scans."""

    robot_sigma_m: float = 0.001
    centre_sigma_m: float = 0.0005
    reference_range_m: float = 0.6
    reference_radius_m: float = 0.02
    reference_scans: int = 120
    scans: int = 120

    def centre_sigma_of(self, range_m: FloatArray, radius_m: float) -> FloatArray:
        """Centre noise (m) per crossing range."""
        ratio = (range_m / self.reference_range_m) * (self.reference_radius_m / radius_m)
        return self.centre_sigma_m * np.sqrt(ratio * self.reference_scans / max(self.scans, 1))


@dataclass(frozen=True)
class Targets:
    """The std the design aims at: the job's quality gates."""

    translation_mm: float
    rotation_deg: float


@dataclass(frozen=True)
class DesignRequest:
    """Everything one design needs."""

    T_base_laser: FloatArray
    rules: CellRules
    targets: Targets
    uncertainty: PoseUncertainty = DEFAULT_UNCERTAINTY
    noise: NoiseModel = field(default_factory=NoiseModel)
    waypoints: int = 20
    seed: int = 0
    candidates: int = 6000
    #: Information already gathered (e.g. the first part of an adaptive run).
    prior_information: FloatArray | None = None
    #: Crossings already visited, kept ``MIN_SEPARATION_M`` away from.
    visited_crossings_m: FloatArray | None = None
    first_index: int = 0
    #: Joints the arm starts from: the tour begins at the waypoint nearest them (home if None).
    start_q_rad: FloatArray | None = None
    #: Design for a run that estimates the rod's axis with the pose (``rod.estimate_axis``).
    estimate_axis: bool = False
    #: ... and this many terms of the scanner's range error curve (0 to 3).
    range_terms: int = 0

    @property
    def parameters(self) -> int:
        """Size of the information: the pose's six, the axis's four and the range curve's terms
        when estimated."""
        return POSE_PARAMETERS + 4 * self.estimate_axis + self.range_terms


@dataclass(frozen=True)
class Design:
    """The designed waypoints in visiting order, their predicted std and what limited them."""

    waypoints: list[Waypoint]
    joints_rad: FloatArray
    information: FloatArray
    std_translation_mm: FloatArray
    std_rotation_deg: FloatArray
    score: float
    weak_direction: str | None
    notes: list[str] = field(default_factory=list)
    candidates_kept: int = 0
    candidates_drawn: int = 0


def request_for_job(
    job: JobConfig,
    T_base_laser: FloatArray,
    model: URModel,
    *,
    uncertainty: PoseUncertainty = DEFAULT_UNCERTAINTY,
    waypoints: int = 20,
    seed: int = 0,
) -> DesignRequest:
    """The design request of a job: its rod, workspace box, quality gates, robot accuracy
    and dwell, for a scanner roughly at ``T_base_laser`` and the robot ``model``."""
    rules = CellRules(
        rod=job.rod.rod_line(),
        box_min_m=tuple(job.workspace.min_m),
        box_max_m=tuple(job.workspace.max_m),
        model=model,
        branch=home_branch(model),
        polished=job.rod.polished,
    )
    noise = NoiseModel(
        robot_sigma_m=job.robot.position_accuracy_mm / 1000.0,
        scans=max(1, round(job.dwell_s / SCAN_PERIOD_S)),
    )
    targets = Targets(job.quality.max_std_translation_mm, job.quality.max_std_rotation_deg)
    return DesignRequest(
        estimate_axis=job.rod.estimate_axis is not False,
        range_terms=0 if job.scanner.estimate_range_offset is False else DESIGN_RANGE_TERMS,
        T_base_laser=np.asarray(T_base_laser, dtype=float),
        rules=rules,
        targets=targets,
        uncertainty=uncertainty,
        noise=noise,
        waypoints=waypoints,
        seed=seed,
    )


def _regulariser(size: int) -> FloatArray:
    """Weak prior that keeps the first greedy steps invertible (1 m, 1 rad): not in the reported CRB."""
    return np.eye(size)


def std_of(information: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Std of translation (mm) and rotation (deg) from a Fisher information (inf if singular);
    any parameters after the pose's six (the rod axis, the range curve) count as unknown."""
    try:
        covariance = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        return np.full(3, np.inf), np.full(3, np.inf)
    std = np.sqrt(np.clip(np.diag(covariance)[:POSE_PARAMETERS], 0.0, None))
    if not np.all(np.isfinite(std)) or np.linalg.cond(information) > 1e14:
        return np.full(3, np.inf), np.full(3, np.inf)
    return std[:3] * 1e3, np.degrees(std[3:])


def _scale(targets: Targets) -> FloatArray:
    """Per-parameter divisor turning std (m, rad) into multiples of the targets."""
    return np.array([targets.translation_mm * 1e-3] * 3 + [np.deg2rad(targets.rotation_deg)] * 3)


def objective(diagonal: FloatArray, scale: FloatArray) -> FloatArray:
    """The objective from the pose's variances (..., 6) (m^2, rad^2): the root of their sum in
    units of the gates, the expected squared norm of the pose's error (what a percentile of
    the error's norm follows), where the largest std alone leaves the other axes free."""
    return np.sqrt((np.clip(diagonal, 0.0, None) / scale**2).sum(axis=-1))


def _scores(information: FloatArray, scale: FloatArray) -> FloatArray:
    """The objective for a stack of information matrices (..., k, k)."""
    diagonal = np.diagonal(np.linalg.inv(information), axis1=-2, axis2=-1)[..., :POSE_PARAMETERS]
    return objective(diagonal, scale)


def information_blocks(
    T_base_tcp: FloatArray, range_m: FloatArray, request: DesignRequest, information: InformationModel
) -> FloatArray:
    """Fisher information block (n, k, k) of each TCP pose at the request's scanner pose,
    the crossing ``range_m`` setting its centre noise."""
    rod = request.rules.rod
    rotation, translation = request.T_base_laser[:3, :3], request.T_base_laser[:3, 3]
    sigma = request.noise.centre_sigma_of(range_m, rod.radius_m)
    blocks = np.empty((len(T_base_tcp), request.parameters, request.parameters))
    for i in range(len(T_base_tcp)):
        covariance = np.eye(2)[None] * sigma[i] ** 2
        blocks[i] = information(
            rotation,
            translation,
            T_base_tcp[i : i + 1],
            rod,
            covariance,
            request.noise.robot_sigma_m,
            with_axis=request.estimate_axis,
            with_offset=request.range_terms,
        )
    return blocks


def visited_crossings(
    T_base_tcp: FloatArray, request: DesignRequest
) -> tuple[FloatArray, FloatArray]:
    """Where the rod held at each TCP pose crosses the request's scan plane: base-frame
    points (n, 3) and ranges from the scanner (n,)."""
    crossings = rod_plane_crossings(T_base_tcp, request.rules.rod, request.T_base_laser)
    points = np.column_stack([crossings.uv_m, np.zeros(len(crossings.uv_m)), np.ones(len(crossings.uv_m))])
    return (points @ request.T_base_laser.T)[:, :3], crossings.range_m


def _rank_two_factors(blocks: FloatArray) -> FloatArray:
    """``L`` (n, k, 2) with ``L L^T`` = each block (a waypoint gives two residual rows)."""
    values, vectors = np.linalg.eigh(blocks)
    return vectors[:, :, -2:] * np.sqrt(np.clip(values[:, None, -2:], 0.0, None))


def _scores_with_each(total: FloatArray, factors: FloatArray, scale: FloatArray) -> FloatArray:
    """The objective of ``total`` plus each candidate's block, by the Woodbury identity
    (no 6 x 6 inverse per candidate)."""
    covariance = np.linalg.inv(total)
    cl = np.einsum("ij,kja->kia", covariance, factors)
    inner = np.eye(2) + np.einsum("kja,kjb->kab", factors, cl)
    diagonal = np.diag(covariance)[None, :] - np.einsum("kia,kab,kib->ki", cl, np.linalg.inv(inner), cl)
    return objective(diagonal[:, :POSE_PARAMETERS], scale)


@dataclass
class _Neighbours:
    """For every candidate, how many chosen ones are too close (crossing) and how many are
    within a joint step (so the chosen set stays one connected region of joint space)."""

    crossings_m: FloatArray
    joints_rad: FloatArray
    crowded: np.ndarray = field(init=False)
    linked: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.crowded = np.zeros(len(self.crossings_m), dtype=int)
        self.linked = np.zeros(len(self.crossings_m), dtype=int)

    def near(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Candidates too close to ``index``'s crossing, and those a joint step away."""
        close = np.linalg.norm(self.crossings_m - self.crossings_m[index], axis=1) < MIN_SEPARATION_M
        difference = np.abs((self.joints_rad - self.joints_rad[index] + np.pi) % (2 * np.pi) - np.pi)
        return close, difference.max(axis=1) <= LINK_STEP_RAD

    def add(self, index: int, sign: int = 1) -> None:
        """Count ``index`` as chosen (``sign`` -1: no longer chosen)."""
        close, link = self.near(index)
        self.crowded += sign * close
        self.linked += sign * link

    def allowed(self, chosen: int) -> np.ndarray:
        """Candidates that may join ``chosen`` others: apart from all, linked to one."""
        return (self.crowded == 0) & ((self.linked > 0) | (chosen == 0))


@dataclass(frozen=True)
class _Search:
    """One selection problem: the candidates' information blocks (with their rank-two
    factors), the objective's scale, which candidates may be used and the information to
    start from."""

    blocks: FloatArray
    factors: FloatArray
    scale: FloatArray
    usable: np.ndarray
    start: FloatArray
    pool: CandidatePool

    def run(self, kept: list[int], count: int) -> tuple[list[int], float]:
        """From ``kept``: greedy up to ``count``, then exchange passes; the set and its score."""
        neighbours = _Neighbours(self.pool.crossing_base_m, self.pool.joints_rad)
        for index in kept:
            neighbours.add(index)
        total = self.start + self.blocks[kept].sum(axis=0)
        chosen, total = self._fill(list(kept), total, count, neighbours)
        chosen, total = self._exchange(chosen, total, neighbours)
        return chosen, float(_scores(total[None], self.scale)[0])

    def _fill(
        self, chosen: list[int], total: FloatArray, count: int, neighbours: _Neighbours
    ) -> tuple[list[int], FloatArray]:
        """Greedy: add the candidate that lowers the objective most until ``count`` are chosen."""
        while len(chosen) < count:
            options = np.flatnonzero(self.usable & neighbours.allowed(len(chosen)))
            if options.size == 0:
                break
            best = int(options[np.argmin(_scores_with_each(total, self.factors[options], self.scale))])
            chosen.append(best)
            neighbours.add(best)
            total = total + self.blocks[best]
        return chosen, total

    def _exchange(
        self, chosen: list[int], total: FloatArray, neighbours: _Neighbours
    ) -> tuple[list[int], FloatArray]:
        """Exchange passes: swap each chosen candidate for the best other one while that helps."""
        for _ in range(EXCHANGE_PASSES):
            improved = False
            for position in range(len(chosen)):
                current = float(_scores(total[None], self.scale)[0])
                leaving = chosen[position]
                neighbours.add(leaving, -1)
                without = total - self.blocks[leaving]
                allowed = self.usable & neighbours.allowed(len(chosen) - 1)
                allowed[chosen] = False
                options = np.flatnonzero(allowed)
                scores = np.zeros(0)
                if options.size:
                    scores = _scores_with_each(without, self.factors[options], self.scale)
                if scores.size and scores.min() < current * (1.0 - 1e-6):
                    chosen[position] = int(options[np.argmin(scores)])
                    improved = True
                neighbours.add(chosen[position])
                total = without + self.blocks[chosen[position]]
            if not improved:
                break
        return chosen, total


def select(
    blocks: FloatArray,
    pool: CandidatePool,
    count: int,
    scale: FloatArray,
    prior: FloatArray,
    usable: np.ndarray,
) -> list[int]:
    """Greedy choice of ``count`` candidates and exchange passes, then one restart from each
    half of that choice (the other half chosen again greedily, then exchanged); the best set
    scored, as indices into the pool. Single swaps stop where the separation and link rules
    fence a better set off (the first picks, made with little information, hold the rest in
    place); a restart from half the set steps over that fence."""
    search = _Search(blocks, _rank_two_factors(blocks), scale, usable, prior + _regulariser(len(prior)), pool)
    best, best_score = search.run([], count)
    half = len(best) // 2
    for kept in (best[half:], best[:half]):
        chosen, score = search.run(kept, count)
        if len(chosen) >= len(best) and score < best_score * (1.0 - 1e-6):
            best, best_score = chosen, score
    return best


def _joint_distance(joints: FloatArray) -> FloatArray:
    """Largest wrapped joint difference between every pair (n, n) (rad)."""
    difference = joints[:, None, :] - joints[None, :, :]
    return np.abs((difference + np.pi) % (2 * np.pi) - np.pi).max(axis=2)


def visiting_order(joints: FloatArray, start_q: FloatArray) -> list[int]:
    """A short open tour in joint space: nearest neighbour from the waypoint closest to
    ``start_q``, then 2-opt."""
    n = len(joints)
    if n == 0:
        return []
    distance = _joint_distance(joints)
    first = int(np.argmin(_joint_distance(np.vstack([start_q, joints]))[0, 1:]))
    order = [first]
    left = set(range(n)) - {first}
    while left:
        nearest = min(left, key=lambda j: distance[order[-1], j])
        order.append(nearest)
        left.remove(nearest)
    improved = True
    while improved:
        improved = False
        for i in range(1, n - 1):
            for j in range(i + 1, n):
                tail_before = distance[order[j], order[j + 1]] if j + 1 < n else 0.0
                tail_after = distance[order[i], order[j + 1]] if j + 1 < n else 0.0
                before = distance[order[i - 1], order[i]] + tail_before
                after = distance[order[i - 1], order[j]] + tail_after
                if after < before - 1e-9:
                    order[i : j + 1] = order[i : j + 1][::-1]
                    improved = True
    return order


def walk_problem(
    transforms: FloatArray, branch_joints: FloatArray, rules: CellRules, start_q: FloatArray
) -> tuple[int | None, FloatArray]:
    """Walk the waypoints with the nearest IK solution from ``start_q``: the position of the
    first waypoint that leaves the branch or jumps too far (None when all pass), and the
    joint angles reached."""
    q_previous = np.asarray(start_q, dtype=float)
    walked = []
    for position, (transform, expected) in enumerate(zip(transforms, branch_joints, strict=True)):
        q = inverse_kinematics(transform, q_previous, model=rules.model)
        off_branch = q is None or np.abs((q - expected + np.pi) % (2 * np.pi) - np.pi).max() > 1e-6
        if off_branch or (position > 0 and np.abs(q - q_previous).max() > MAX_JOINT_STEP_RAD):
            return position, np.array(walked)
        walked.append(q)
        q_previous = q
    return None, np.array(walked)


def describe_weakness(
    information: FloatArray, targets: Targets, pool: CandidatePool, std_t: FloatArray, std_r: FloatArray
) -> str:
    """Which combination of parameters the design leaves weakest, and what limited it."""
    removed = sorted(pool.removed.items(), key=lambda item: -item[1])[:2]
    limits = "; ".join(f"{rule}: {count}" for rule, count in removed if count)
    if len(pool) == 0:
        return f"no pose passes every rule (of {pool.drawn} drawn, most removed by {limits})"
    scale = _scale(targets)
    try:
        covariance = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        covariance = np.linalg.pinv(information)
    pose = covariance[:POSE_PARAMETERS, :POSE_PARAMETERS]
    normalised = pose / np.outer(scale, scale)
    _, vectors = np.linalg.eigh(normalised)
    vector = vectors[:, -1] / np.abs(vectors[:, -1]).max()
    parts = [_AXES[k] for k in np.argsort(-np.abs(vector)) if abs(vector[k]) >= 0.35]
    direction = parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]
    verb = "stays" if len(parts) == 1 else "together stay"
    worst = (
        f"translation std {std_t.max():.2f} mm (target {targets.translation_mm:g} mm)"
        if std_t.max() / targets.translation_mm >= std_r.max() / targets.rotation_deg
        else f"rotation std {std_r.max():.3f} deg (target {targets.rotation_deg:g} deg)"
    )
    bearings = np.degrees(pool.crossing_bearing_rad)
    return (
        f"{direction} {verb} weak ({worst}): the arm reaches the scan plane only at bearings "
        f"{bearings.min():+.0f}..{bearings.max():+.0f} deg and {pool.crossing_range_m.min():.2f}-"
        f"{pool.crossing_range_m.max():.2f} m from the scanner ({len(pool)} of {pool.drawn} drawn poses pass "
        f"every rule; most removed by {limits}), a short lever for that direction"
    )


def _search_one_side(
    blocks: FloatArray,
    pool: CandidatePool,
    request: DesignRequest,
    prior: FloatArray,
    usable: np.ndarray,
    on_progress: Callable[[float], None] | None,
) -> tuple[list[int], FloatArray, bool]:
    """Choose and order waypoints among ``usable``; a waypoint that breaks the walk is
    dropped and the choice repeated. Returns the chosen indices in visiting order, the
    joints walked, and whether the whole choice could be walked."""
    usable = usable.copy()
    chosen: list[int] = []
    walked = np.zeros((0, 6))
    for round_index in range(_WALK_ROUNDS):
        if on_progress is not None:
            on_progress(round_index / _WALK_ROUNDS)
        chosen = select(blocks, pool, request.waypoints, _scale(request.targets), prior, usable)
        start_q = HOME_Q_RAD if request.start_q_rad is None else np.asarray(request.start_q_rad)
        order = visiting_order(pool.joints_rad[chosen], start_q)
        chosen = [chosen[k] for k in order]
        start = HOME_Q_RAD if not chosen else pool.joints_rad[chosen[0]]
        failed_at, walked = walk_problem(
            pool.T_base_tcp[chosen], pool.joints_rad[chosen], request.rules, start
        )
        if failed_at is None:
            return chosen, walked, True
        usable[chosen[failed_at]] = False
    return chosen[: len(walked)], walked, False


def design(
    request: DesignRequest, information: InformationModel, on_progress: ProgressCallback | None = None
) -> Design:
    """Design ``request.waypoints`` waypoints for the cell (seeded by ``request.seed``)."""
    rng = np.random.default_rng(request.seed)
    rules = request.rules
    pool = draw_candidates(
        request.T_base_laser,
        request.uncertainty,
        rules,
        request.candidates,
        rng,
        turn_spread_deg=AXIS_TOOL_TURN_SPREAD_DEG if request.estimate_axis else TOOL_TURN_SPREAD_DEG,
        on_progress=None if on_progress is None else (lambda f: on_progress("candidate poses", f)),
    )
    if on_progress is not None:
        on_progress("information", 0.0)
    blocks = information_blocks(pool.T_base_tcp, pool.crossing_range_m, request, information)
    size = request.parameters
    prior = np.zeros((size, size)) if request.prior_information is None else request.prior_information
    visited = (
        np.zeros((0, 3)) if request.visited_crossings_m is None else np.asarray(request.visited_crossings_m)
    )
    scale = _scale(request.targets)
    excluded = np.zeros(len(pool), dtype=bool)
    if len(visited):
        distance = np.linalg.norm(pool.crossing_base_m[:, None, :] - visited[None, :, :], axis=2)
        excluded |= np.any(distance < MIN_SEPARATION_M, axis=1)
    notes: list[str] = []
    best: tuple[float, list[int], FloatArray, bool] | None = None
    sides = [side for side in (1.0, -1.0) if np.any(~excluded & (pool.side == side))]
    for k, side in enumerate(sides):
        chosen, walked, complete = _search_one_side(
            blocks, pool, request, prior, ~excluded & (pool.side == side),
            None if on_progress is None else (lambda f, k=k: on_progress("search", (k + f) / len(sides))),
        )
        score = float(_scores((prior + _regulariser(size) + blocks[chosen].sum(axis=0))[None], scale)[0])
        if best is None or (len(chosen), -score) > (len(best[1]), -best[0]):
            best = (score, chosen, walked, complete)
    chosen, walked, complete = ([], np.zeros((0, 6)), True) if best is None else best[1:]
    if not complete:
        notes.append("the visiting order still broke the joint-jump rule; the design was cut short there")
    if on_progress is not None:
        on_progress("search", 1.0)
    if len(chosen) < request.waypoints:
        notes.append(
            f"only {len(chosen)} of {request.waypoints} waypoints found that keep every rule "
            f"and {MIN_SEPARATION_M * 100:.0f} cm apart"
        )
    total = prior + blocks[chosen].sum(axis=0)
    std_t, std_r = std_of(total)
    targets = request.targets
    score = max(float(std_t.max()) / targets.translation_mm, float(std_r.max()) / targets.rotation_deg)
    weak = describe_weakness(total, request.targets, pool, std_t, std_r) if score > 1.0 else None
    poses = matrix_to_pose(pool.T_base_tcp[chosen]) if chosen else np.zeros((0, 6))
    waypoints = [
        Waypoint(
            index=request.first_index + k,
            tcp_pose=tuple(float(v) for v in pose),
            label=(
                f"designed: crossing {pool.crossing_range_m[i]:.2f} m at "
                f"{np.degrees(pool.crossing_bearing_rad[i]):+.0f} deg"
            ),
        )
        for k, (i, pose) in enumerate(zip(chosen, poses, strict=True))
    ]
    return Design(
        waypoints=waypoints,
        joints_rad=walked,
        information=total,
        std_translation_mm=std_t,
        std_rotation_deg=std_r,
        score=score,
        weak_direction=weak,
        notes=notes,
        candidates_kept=len(pool),
        candidates_drawn=pool.drawn,
    )
