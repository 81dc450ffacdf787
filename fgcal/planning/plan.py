"""``fgcal plan``: choose the measurement configurations of a calibration cell.

Writes ``configurations.csv`` (``config, q1..qn`` in rad and, for camera cells, the block
each configuration looks at: ``fgcal simulate --configurations`` and a real cell's program
read it; with the unidirectional strategy, ``before_q1..before_qn``: the approach point of
each, the same offset below on every joint), ``plan.json`` (SI) and ``plan.md`` (mm) with the predicted accuracy, the
observability indices and the condition number, and ``predicted_accuracy.png``: predicted
accuracy against N for the planned design beside random and space-filling ones.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..calibration.config import CalibrationConfig
from ..calibration.formulations import REGISTRY
from ..calibration.formulations import formulation as registered
from ..calibration.plan_model import PAIR_GROUPS_FILE, Candidates, Planning, pair_groups_setting
from ..calibration.settings import MeasurementSettings
from ..core import strict_json
from ..core.errors import InputError
from ..core.outputs import output_dir, save_figure, write_text
from ..data.dataset import write_csv
from ..model import kinematics
from ..model.motion import MotionHistory, features
from ..model.robot import MODELS
from ..simulation.cell import Cell, load_cell
from ..simulation.design import max_min_selection
from . import MAX_CANDIDATES
from .exchange import CRITERIA, criterion_value, information_of, plan_design, predicted_sigma, with_repeats
from .groups import RANDOM_DRAWS as GROUP_DRAWS
from .groups import group_information, plan_groups, random_groups_sigma
from .indices import observability
from .information import Information, build_information

RANDOM_DRAWS = 5
REFERENCE_SIZE = 300
APPROACHES = ("previous", "unidirectional", "varied")
# A varied approach moves each joint by this fraction of the approach offset or more, so that the
# speed term (its share of the largest move) and the lost motion (saturating past 1 deg) part.
VARIED_LEAST = 0.25
APPROACH_OFFSET_RAD = float(np.radians(2.0))
# Every file fgcal plan writes in its --out folder (plan.json marks a plan's folder): of an
# earlier plan there, those the new plan does not write are removed (a controller program of the
# old plan must not sit beside the new configurations).
PLAN_FILES = (
    "configurations.csv", "plan.json", "plan.md", PAIR_GROUPS_FILE, "predicted_accuracy.png",
    "cal_plan.mod", "cal_plan.src", "cal_plan.dat", "configurations_deg.csv",
)  # fmt: skip
# The scored point of a camera cell: on the optical axis at the middle of the designs' standoff (m).
SCORED_POINT_C = np.array([0.0, 0.0, 0.4])


@dataclass
class PlanResult:
    cell: str
    robot: str
    formulation: str
    model: str
    criterion: str
    seed: int
    n: int
    candidates: Candidates
    info: Information
    chosen: list[int]
    predicted_sigma_m: float
    space_filling_sigma_m: float
    indices: dict[str, float]
    curves: dict[str, list[float]]
    timing_s: dict[str, float] = field(default_factory=dict)
    # "previous": each configuration reached from the one before; "unidirectional": from below on
    # every joint; "varied": each from its own approach point (``approach_before``), within the
    # offset above or below on each joint (model DH,s,e,h)
    approach: str = "previous"
    approach_offset_rad: float = APPROACH_OFFSET_RAD
    # With the cell's motion_history: what its lost motion leaves that no static model absorbs (m)
    lost_motion: dict | None = None
    # What the model does not describe on the real robot (m RMS at a point), and where it came
    # from (--model-error, or an earlier calibration's report.json); None: not given.
    model_error_m: float | None = None
    model_error_source: str | None = None
    approach_before: np.ndarray | None = None  # (M, n) each candidate's approach point, or None
    # Pairs: the groups the calibration is to fit the images in (positions in ``chosen``), which
    # the prediction assumes (pair_groups.csv, ``pairs: {groups: pair_groups.csv}``), and the
    # prediction with random groups instead (m, RMS over groups.RANDOM_DRAWS partitions); None: no groups.
    pair_groups: list[list[int]] | None = None
    random_groups_sigma_m: float | None = None

    @property
    def expected_m(self) -> float | None:
        """What a real robot will show (m RMS), given its model error: the floor and the
        model error in quadrature (docs/planning.md); None without a model error."""
        if self.model_error_m is None:
            return None
        return float(np.hypot(self.predicted_sigma_m, self.model_error_m))

    def prediction(self) -> dict:
        return {
            "floor_m": self.predicted_sigma_m,
            "floor_holds_if": "the model describes the robot and the noise is as declared",
            "model_error_m": self.model_error_m,
            "model_error_source": self.model_error_source,
            "expected_rms_m": self.expected_m,
            "formula": "expected = sqrt(floor^2 + model_error^2)",
        }

    def prediction_lines(self) -> list[str]:
        """The prediction in words: the floor, and what a real robot shows (or how to ask)."""
        floor = (
            f"predicted position accuracy {_mm(self.predicted_sigma_m)} mm RMS over the region: the floor, if the "
            "model describes the robot (the noise alone)"
        )
        if self.model_error_m is None:
            return [
                floor,
                "a real robot shows more: what its model does not describe adds in quadrature (the IRB 120 on real "
                "tracker data holds out 0.27-0.45 mm); give --model-error MM, or --model-error-from an earlier "
                "calibration's report.json, to predict it",
            ]
        return [
            floor,
            f"with a model error of {_mm(self.model_error_m)} mm RMS ({self.model_error_source}), a real robot is "
            f"expected to hold out {_mm(self.expected_m)} mm RMS = sqrt(floor^2 + model error^2)",
        ]

    @property
    def drawn(self) -> int:
        """Configurations drawn for the candidates: those kept and those discarded."""
        return len(self.candidates.q) + sum(self.candidates.discarded.values())

    @property
    def unseen(self) -> dict | None:
        """Of what the plan's configurations would measure, how much the instrument does not
        see (not measured, and not counted in the prediction); None: it sees everything."""
        seen = self.candidates.seen
        if seen is None:
            return None
        chosen = seen[self.chosen]
        return {
            "what": self.candidates.seen_label,
            "measured": int(chosen.sum()),
            "out_of_view": int(chosen.size - chosen.sum()),
            "configurations_seeing_all": int(chosen.all(axis=1).sum()),
        }

    def discarded_lines(self) -> list[str]:
        """Why draws were discarded before planning, one line each."""
        lines = [
            f"{count} of {self.drawn} drawn configurations discarded: {reason}"
            for reason, count in self.candidates.discarded.items()
        ]
        unseen = self.unseen
        if unseen is not None and unseen["out_of_view"]:
            lines.append(
                f"the plan's configurations measure {unseen['measured']} {unseen['what']}; "
                f"{unseen['out_of_view']} others are out of the instrument's view (not measured, not counted)"
            )
        return lines

    @property
    def approach_points(self) -> np.ndarray | None:
        """(n, joints) the approach point of each planned configuration (unidirectional or
        varied), or None."""
        if self.approach_before is None:
            return None
        return self.approach_before[self.chosen]

    def to_json(self) -> dict:
        return {
            "cell": self.cell,
            "robot": self.robot,
            "formulation": self.formulation,
            "model": self.model,
            "criterion": self.criterion,
            "seed": self.seed,
            "n_configurations": self.n,
            "n_candidates": len(self.candidates.q),
            "n_drawn": self.drawn,
            "discarded": dict(self.candidates.discarded),
            "out_of_view": self.unseen,
            "parameters": self.info.names,
            "auxiliary_unknowns": self.info.aux_labels,
            "unidentifiable": self.info.unidentifiable,
            "measurement_sigma_m": self.info.sigma_m if self.info.unit == "m" else None,
            "measurement_sigma": {"value": self.info.sigma_m, "unit": self.info.unit},
            "gauge_removed": self.info.gauge,
            "predicted_position_sigma_rms_m": self.predicted_sigma_m,
            "prediction": self.prediction(),
            "space_filling_same_n_sigma_rms_m": self.space_filling_sigma_m,
            "observability": self.indices,
            "curves": self.curves,
            "cpu_time_s": self.timing_s,
            "approach": self.approach,
            "approach_offset_rad": self.approach_offset_rad if self.approach != "previous" else None,
            "lost_motion": self.lost_motion,
            "pair_groups": self.pair_groups_json(),
        }

    def config_id(self, k: int) -> str:
        """The id configurations.csv gives the plan's k-th configuration."""
        return f"p{k:04d}"

    def pair_groups_json(self) -> dict | None:
        if self.pair_groups is None:
            return None
        return {
            "file": PAIR_GROUPS_FILE,
            "config": pair_groups_setting(PAIR_GROUPS_FILE),
            "groups": [[self.config_id(k) for k in group] for group in self.pair_groups],
            "prediction_holds_for": "these groups (the calibration config's pairs.groups naming the file)",
            "random_groups_predicted_position_sigma_rms_m": self.random_groups_sigma_m,
            "random_groups_draws": GROUP_DRAWS,
        }

    def pair_groups_line(self) -> str | None:
        """What the plan's pair groups are and how to calibrate with them, in words."""
        if self.pair_groups is None:
            return None
        return (
            f"the prediction holds for the pair groups of {PAIR_GROUPS_FILE} ({len(self.pair_groups)} groups, "
            f"chosen for the least predicted error): calibrate with `pairs: {{groups: {PAIR_GROUPS_FILE}}}` in the "
            f"calibration config (the path relative to the config); with random groups of {self.info.grouping.size} "
            f"instead (the calibration's default), {_mm(self.random_groups_sigma_m)} mm RMS (over {GROUP_DRAWS} draws)"
        )


def _curve_sizes(n: int, n_candidates: int, n_unknowns: int) -> list[int]:
    sizes = {6, 9, 12, 18, 24, 36, 48, 72, 100, 150, 200, 300, n}
    low = max(3, int(np.ceil(n_unknowns / 12)))
    return sorted(s for s in sizes if low <= s <= min(n_candidates, max(3 * n, 100)))


def _curves(planner: Planner, greedy: list[int], sizes: list[int]) -> dict[str, list[float]]:
    """Predicted RMS sigma (m) against N: the greedy sequence's prefixes (the plan's own
    algorithm before its exchange passes), random designs (mean of RANDOM_DRAWS) and
    space-filling designs (max-min in joint space) from the same candidates."""
    info, n_candidates = planner.info, len(planner.candidates.q)
    rng = np.random.default_rng(planner.seed)
    planned, random, space_filling = [], [], []
    for size in sizes:
        planned.append(predicted_sigma(info, information_of(info, greedy[:size])) if size <= len(greedy) else None)
        draws = [rng.choice(n_candidates, size, replace=False) for _ in range(RANDOM_DRAWS)]
        random.append(float(np.mean([predicted_sigma(info, information_of(info, d)) for d in draws])))
        space_filling.append(predicted_sigma(info, information_of(info, planner.space_filling(size))))
    return {"n": sizes, "planned_m": planned, "random_m": random, "space_filling_m": space_filling}


@dataclass
class Planner:
    """A cell's candidates and their information, ready to plan designs of any size."""

    cell: Cell
    formulation: str
    model: str
    seed: int
    candidates: Candidates
    info: Information
    timing_s: dict[str, float]
    planning: Planning  # what the formulation measures (Formulation.planning)
    approach: str = "previous"
    approach_before: np.ndarray | None = None  # (M, n) each candidate's approach point, or None

    def space_filling(self, n: int) -> list[int]:
        return max_min_selection(self.candidates.q, self.cell.robot.limits, n, np.random.default_rng(self.seed + 1))

    def check_size(self, n: int) -> None:
        n_rows, n_unknowns = self.info.rows.shape[1], self.info.n_params + len(self.info.aux_labels)
        if not 1 <= n <= len(self.candidates.q):
            raise InputError(
                None, "--n", f"plan 1 to {len(self.candidates.q)} (the candidates) configurations, got {n}"
            )
        if n * n_rows < n_unknowns:
            raise InputError(
                None,
                "--n",
                f"{n} configurations give {n * n_rows} measurement rows for {self.info.n_params} parameters and "
                f"{len(self.info.aux_labels)} auxiliary unknowns: plan more configurations",
            )


def _planned() -> dict[str, str]:
    """The formulations fgcal plan models (their ``planning`` is not None), in the registry's
    order, and the instrument each reads."""
    settings = MeasurementSettings()
    return {name: cls.instrument for name, cls in REGISTRY.items() if cls().planning(settings) is not None}


# The formulations fgcal plan models, and the instruments they read.
PLANNED = _planned()
PLANNED_INSTRUMENTS = tuple(dict.fromkeys(PLANNED.values()))


def choose_formulation(cell: Cell, formulation: str | None) -> str:
    """The formulation to plan for: the one asked for, if the planner models it and the cell
    has its instrument; by default the first formulation the cell's instruments serve."""
    available = [kind for kind in cell.instruments if kind in PLANNED_INSTRUMENTS]
    if formulation is None:
        for kind in available:
            for name, reads in PLANNED.items():
                if reads == kind:
                    return name
        raise InputError(
            cell.source,
            None,
            f"this cell has neither of the instruments fgcal plan models ({', '.join(PLANNED_INSTRUMENTS)}); "
            "touch and ballbar cells are not planned yet",
        )
    if formulation not in REGISTRY:
        raise InputError(None, "--formulation", f"unknown formulation {formulation!r} (one of {', '.join(REGISTRY)})")
    kind = PLANNED.get(formulation)
    if kind is None:
        raise InputError(
            None, "--formulation", f"the {formulation} formulation is not planned yet (planned: {', '.join(PLANNED)})"
        )
    if kind not in available:
        raise InputError(
            cell.source,
            kind,
            f"the {formulation} formulation needs a {kind}, and this cell has "
            + (" and ".join(available) if available else "none that fgcal plan models"),
        )
    return formulation


def prepare(
    cell_path: str | Path,
    n_candidates: int = 5000,
    formulation: str | None = None,
    model: str = "DH,s,e",
    seed: int = 1,
    reference_size: int = REFERENCE_SIZE,
    progress: Callable[[str], None] | None = None,
    approach_offset_rad: float = 0.0,
    approach: str | None = None,
) -> Planner:
    """Candidates of the cell (seeded) and their information rows on the parameters that a
    space-filling design of ``reference_size`` determines (a parameter the planned design
    cannot determine keeps its prior, its plausible deviation, in the prediction). With
    ``approach_offset_rad`` and the ``unidirectional`` approach, candidates leave that much
    room above each lower joint limit, for an approach from below. ``approach`` (default:
    ``varied`` for a model with the motion history's terms, else ``previous``): how each
    candidate is reached, which a model with those terms sees (approach_points)."""
    say = progress or (lambda _msg: None)
    if model not in MODELS:
        raise InputError(None, "--model", f"unknown model {model!r} (one of {MODELS})")
    approach = approach or default_approach(model)
    if approach not in APPROACHES:
        raise InputError(None, "--approach", f"unknown approach {approach!r} (one of {', '.join(APPROACHES)})")
    if approach != "previous" and approach_offset_rad <= 0.0:  # an approach point needs a distance
        approach_offset_rad = APPROACH_OFFSET_RAD
    if approach == "previous" and _has_motion_terms(model):
        raise InputError(
            None, "--approach", f"model {model} fits the lost motion, which depends on how each configuration is "
            "reached: in the plan's order (previous) that is not known while choosing; plan with --approach varied "
            "(each configuration from its own approach point, above or below on each joint)",
        )  # fmt: skip
    if not 1 <= n_candidates <= MAX_CANDIDATES:
        raise InputError(None, "--candidates", f"1 to {MAX_CANDIDATES} candidates, got {n_candidates}")
    cell = load_cell(cell_path)
    formulation = choose_formulation(cell, formulation)
    robot = cell.robot.with_model(model)
    if approach == "unidirectional":
        limits = robot.limits.copy()
        limits[:, 0] += approach_offset_rad
        if np.any(limits[:, 0] >= limits[:, 1]):
            raise InputError(None, "--approach-offset", "leaves no room within a joint's limits")
        robot = replace(robot, limits=limits)
    cell = replace(cell, robot=robot)
    # The compliant joints the cell declares (those fgcal simulate's calibration.yaml names).
    compliant = [int(j) for j in cell.perturbation.compliant_joints]
    config = CalibrationConfig.defaults(".", formulation=formulation, model=model, compliant_joints=compliant)
    planning = registered(formulation).planning(config.measurement)
    if planning is None:  # choose_formulation planned it: its planning does not depend on settings
        raise InputError(None, "--formulation", f"the {formulation} formulation is not planned yet")
    rng = np.random.default_rng(seed)
    timing: dict[str, float] = {}
    started = time.process_time()
    cand = planning.candidates(cell, n_candidates, rng, progress=say)
    timing["candidates"] = time.process_time() - started
    started = time.process_time()
    size = min(len(cand.q), reference_size)
    reference = np.array(max_min_selection(cand.q, robot.limits, size, np.random.default_rng(seed + 1)))
    # Where the approach is the plan's, the candidates' and the region's (an independent stream).
    approach_rng = np.random.default_rng(seed + 2)
    before = approach_points(cand.q, robot.limits, approach, approach_offset_rad, approach_rng)
    region_approach = lambda q: approach_points(q, robot.limits, approach, approach_offset_rad, approach_rng)  # noqa: E731
    info = build_information(
        cell, robot, cand, config, planning, reference, seed=seed, before=before, region_before=region_approach
    )
    timing["information"] = time.process_time() - started
    say(f"  {info.n_params} identifiable parameters, {len(info.aux_labels)} auxiliary unknowns")
    return Planner(cell, formulation, model, seed, cand, info, timing, planning, approach, before)


def _has_motion_terms(model: str) -> bool:
    return "h" in model.split(",")


def default_approach(model: str) -> str:
    """``varied`` for a model with the motion history's terms (they need configurations reached
    from different directions and distances), else ``previous``."""
    return "varied" if _has_motion_terms(model) else "previous"


def approach_points(
    q: np.ndarray, limits: np.ndarray, approach: str, offset_rad: float, rng: np.random.Generator
) -> np.ndarray | None:
    """(N, n) the approach point of each configuration: ``unidirectional``, ``offset_rad``
    below on every joint; ``varied``, on each joint above or below at random by
    VARIED_LEAST to 1 times ``offset_rad`` (below where above would leave the limits, and the
    other way round), so that the lost motion (the direction of the last move) and the speed
    term (each joint's share of the largest move) vary from configuration to configuration;
    ``previous``: None (reached from the one before: not known while choosing)."""
    if approach == "unidirectional":
        return q - offset_rad
    if approach != "varied":
        return None
    sign = rng.choice([-1.0, 1.0], size=q.shape)
    step = rng.uniform(VARIED_LEAST, 1.0, size=q.shape) * offset_rad
    outside = (q - sign * step < limits[:, 0]) | (q - sign * step > limits[:, 1])
    sign[outside] *= -1.0
    return q - sign * step


def plan(
    cell_path: str | Path,
    n: int,
    criterion: str = "d-optimal",
    n_candidates: int = 5000,
    formulation: str | None = None,
    model: str = "DH,s,e",
    seed: int = 1,
    curve_max: int | None = None,
    progress: Callable[[str], None] | None = None,
    planner: Planner | None = None,
    approach: str | None = None,
    approach_offset_rad: float = APPROACH_OFFSET_RAD,
    model_error_m: float | None = None,
    model_error_source: str | None = None,
) -> PlanResult:
    """Plan ``n`` configurations of the cell from ``n_candidates`` (seeded); ``planner``:
    prepared candidates to reuse (then the cell and candidate options are its own).
    ``approach``: ``previous`` (each configuration reached from the one before, in the plan's
    order), ``unidirectional`` (each from ``approach_offset_rad`` below on every joint: its
    lost motion is then the same everywhere, and the joint offsets absorb it) or ``varied``
    (each from its own approach point: model DH,s,e,h's motion terms identifiable); default
    by the model (default_approach). ``model_error_m``:
    what the model does not describe on the real robot (m RMS; ``model_error_source`` says
    where it came from), for the prediction of what a real robot shows."""
    say = progress or (lambda _msg: None)
    if model_error_m is not None and not (np.isfinite(model_error_m) and model_error_m >= 0.0):
        raise InputError(None, "--model-error", f"a model error of 0 or more, got {model_error_m}")
    if criterion not in CRITERIA:
        raise InputError(None, "--criterion", f"unknown criterion {criterion!r} (one of {', '.join(CRITERIA)})")
    if approach is not None and approach not in APPROACHES:
        raise InputError(None, "--approach", f"unknown approach {approach!r} (one of {', '.join(APPROACHES)})")
    if not 0.0 < approach_offset_rad <= np.radians(30.0):
        raise InputError(None, "--approach-offset", "an approach offset in (0, 30] degrees")
    if planner is None:
        if not 1 <= n <= n_candidates:  # before the candidates are drawn: they take a while
            raise InputError(None, "--n", f"plan 1 to {n_candidates} (the candidates) configurations, got {n}")
        size = max(n, REFERENCE_SIZE)
        planner = prepare(cell_path, n_candidates, formulation, model, seed, size, say, approach_offset_rad, approach)
        say(f"planning {n} configurations of {cell_path} ({planner.formulation}, {model}) by {criterion}")
    planner.check_size(n)
    approach = planner.approach
    info, cand, robot = planner.info, planner.candidates, planner.cell.robot
    timing = dict(planner.timing_s)
    started = time.process_time()
    sizes = _curve_sizes(n, len(cand.q), info.n_params + len(info.aux_labels))
    if curve_max is not None:
        sizes = [s for s in sizes if s <= curve_max]
    # One greedy sequence, to the largest size, gives every prefix: the curve's planned
    # designs and the start of this plan's exchange.
    greedy = plan_design(info, max([n, *sizes]), criterion, max_passes=0)[1]
    chosen, _ = plan_design(info, n, criterion, progress=say, greedy_order=greedy)
    # The greedy start is myopic where a measurement tells nothing until it is repeated (a point
    # touched once only locates itself): the exchange from the space-filling design too, the
    # better of the two kept.
    other, _ = plan_design(info, n, criterion, start=planner.space_filling(n))
    if criterion_value(info, other, criterion) > criterion_value(info, chosen, criterion) + 1e-9:
        say("  the exchange from the space-filling design is better than from the greedy one: taken")
        chosen = other
    if cand.blocks is not None and cand.min_per_label > 1:
        chosen = with_repeats(info, chosen, cand.blocks, cand.min_per_label, criterion)
    timing["selection"] = time.process_time() - started
    started = time.process_time()
    curves = _curves(planner, greedy, sizes)
    timing["curves"] = time.process_time() - started
    M = information_of(info, chosen)
    random_groups_sigma_m, groups = None, None
    if info.grouping is not None:  # pairs: the groups the calibration is to fit, chosen for the least error
        started = time.process_time()
        random_groups_sigma_m = random_groups_sigma(info, chosen, planner.seed)
        groups = plan_groups(info, chosen, planner.seed)
        M = group_information(info, chosen, groups)
        timing["pair_groups"] = time.process_time() - started
    n_rows = info.rows.shape[1]
    return PlanResult(
        cell=planner.cell.name,
        robot=robot.name,
        formulation=planner.formulation,
        model=planner.model,
        criterion=criterion,
        seed=planner.seed,
        n=n,
        candidates=cand,
        info=info,
        chosen=chosen,
        predicted_sigma_m=predicted_sigma(info, M),
        space_filling_sigma_m=predicted_sigma(info, information_of(info, planner.space_filling(n))),
        indices=observability(M, info, n * n_rows, with_prior=False),
        curves=curves,
        timing_s=timing,
        approach=approach,
        approach_offset_rad=float(approach_offset_rad),
        lost_motion=lost_motion_left(planner.cell, cand.q[chosen], approach_offset_rad),
        model_error_m=None if model_error_m is None else float(model_error_m),
        model_error_source=model_error_source or ("--model-error" if model_error_m is not None else None),
        approach_before=planner.approach_before,
        pair_groups=groups,
        random_groups_sigma_m=random_groups_sigma_m,
    )


def model_error_from_report(path: str | Path, robot: str | None = None, model: str | None = None) -> float:
    """What a model left unexplained on a robot, from an earlier calibration's report.json
    (m RMS): the held-out position error after calibration beyond what that calibration
    predicted of it (its noise and parameter uncertainty), ``sqrt(max(held_out^2 -
    predicted^2, 0))``. With ``robot`` and ``model`` (the plan's): the report must be of that
    robot and model (docs/planning.md: another's residual level says nothing of this one)."""
    import json

    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(path, None, f"not a readable report.json: {exc}") from None
    for key, wanted, what in (("robot", robot, "the cell's robot"), ("model", model, "the plan's --model")):
        if wanted is None:
            continue
        given = doc.get(key) if isinstance(doc, dict) else None
        if given != wanted:
            found = f"is of {key} {given!r}" if given is not None else f"names no {key}"
            raise InputError(
                path, key, f"{found}, not {wanted!r} ({what}): the model error comes from an earlier calibration "
                "of the same robot and model (or give --model-error MM)",
            )  # fmt: skip
    validation = doc.get("validation") if isinstance(doc, dict) else None
    try:
        held_out = float(validation["after"]["position_error_m"]["rms"])
        predicted = float(validation["predicted_position_sigma_m"]["rms"])
    except (KeyError, TypeError, ValueError):
        raise InputError(
            path,
            "validation",
            "no held-out position error after calibration and its prediction (validation.after.position_error_m.rms, "
            "validation.predicted_position_sigma_m.rms): a calibration's report.json with held-out configurations",
        ) from None
    if not (np.isfinite(held_out) and np.isfinite(predicted)) or held_out < 0 or predicted < 0:
        raise InputError(path, "validation", "held-out and predicted RMS must be finite numbers >= 0")
    return float(np.sqrt(max(held_out**2 - predicted**2, 0.0)))


def lost_motion_left(cell: Cell, q: np.ndarray, offset_rad: float) -> dict | None:
    """What the cell's declared lost motion (motion_history) leaves at the scored point that no
    static model absorbs, RMS over the plan's configurations (m): visited in the plan's order,
    and each approached from ``offset_rad`` below. Each joint's offset splits into the constant
    that the joint offsets absorb (its least-squares value over the plan) and the rest."""
    if cell.motion is None:
        return None
    robot = cell.robot.with_model("DH,s,e,h")
    params = {**robot.nominal_parameters(), **cell.motion.parameters()}
    point = cell.tracker_targets[0] if cell.camera is None else SCORED_POINT_C
    frame = "flange" if cell.camera is None else "tool"
    J = robot.jacobian(q, [f"q{i}" for i in range(1, robot.n_joints + 1)], params, frame=frame, point=point)
    vector = robot.parameter_vector(params)
    out = {}
    for label, history in (
        ("in_order_rms_m", MotionHistory.in_order(q)),
        ("unidirectional_rms_m", MotionHistory(q - offset_rad, np.ones(len(q)))),
    ):
        offsets = kinematics.motion_offsets(robot, vector, features(q, history))
        # The constant joint offsets c that best absorb them: min sum |J (offsets - c)|^2.
        A = J.reshape(-1, robot.n_joints)
        c = np.linalg.lstsq(A, np.einsum("nij,nj->ni", J, offsets).reshape(-1), rcond=None)[0]
        left = np.einsum("nij,nj->ni", J, offsets - c)
        rms = float(np.sqrt(np.mean(np.sum(left**2, axis=1))))
        out[label] = rms if rms > 1e-12 else 0.0  # rounding: the offsets are constant
    return out


def check_out(out_dir: str | Path, inputs: dict[str, str | Path | None]) -> None:
    """Refuse an --out folder before planning: a dataset's folder (its configurations.csv would
    be replaced, and the dataset no longer calibrates), or one where a file the plan writes is
    one of its ``inputs`` (the cell, the report, through links too)."""
    from ..core.outputs import distinct

    out = Path(out_dir)
    if (out / "dataset.yaml").exists():
        raise InputError(
            out, "--out", "holds a dataset (dataset.yaml): the plan would replace its configurations.csv; "
            "name another folder for the plan",
        )  # fmt: skip
    given = {role: path for role, path in inputs.items() if path is not None and Path(path).is_file()}
    distinct({f"--out ({name})": out / name for name in PLAN_FILES}, given)


def remove_earlier_plan(out_dir: str | Path, written: list[str], had_plan: bool) -> list[str]:
    """The files of an earlier plan in ``out_dir`` (it held a plan.json before this one was
    written) that this plan did not write: removed (fgcal plan's own output names only, never a
    folder), their names returned."""
    if not had_plan:
        return []
    removed = []
    for name in PLAN_FILES:
        path = Path(out_dir) / name
        if name not in written and (path.is_symlink() or path.is_file()):
            path.unlink()  # a link itself, never what it points at
            removed.append(name)
    return removed


def write_plan(result: PlanResult, out_dir: str | Path, plot: bool = True) -> list[str]:
    out = output_dir(out_dir)
    cand, chosen = result.candidates, result.chosen
    n_joints = cand.q.shape[1]
    header = ["config", *[f"q{i}" for i in range(1, n_joints + 1)]]
    rows = [[result.config_id(k), *cand.q[c]] for k, c in enumerate(chosen)]
    if cand.blocks is not None:
        header.append(cand.label_column)
        rows = [[*row, cand.blocks[c]] for row, c in zip(rows, chosen, strict=True)]
    approach = result.approach_points
    if approach is not None:
        header += [f"before_q{i}" for i in range(1, n_joints + 1)]
        rows = [[*row, *map(float, before)] for row, before in zip(rows, approach, strict=True)]
    write_csv(out / "configurations.csv", header, rows)
    write_text(out / "plan.json", strict_json.dumps(result.to_json(), indent=2) + "\n")
    write_text(out / "plan.md", _markdown(result, plot))
    written = ["configurations.csv", "plan.json", "plan.md"]
    if result.pair_groups is not None:
        write_pair_groups(result, out / PAIR_GROUPS_FILE)
        written.append(PAIR_GROUPS_FILE)
    if plot:
        _plot(result, out / "predicted_accuracy.png")
        written.append("predicted_accuracy.png")
    return written


def write_pair_groups(result: PlanResult, path: Path) -> None:
    """``config,group``: the group of each planned configuration, as the calibration's
    ``pairs.groups`` reads it."""
    rows = [[result.config_id(k), f"g{g + 1:02d}"] for g, group in enumerate(result.pair_groups) for k in group]
    comments = [f"# The pair groups fgcal plan chose (calibration config: pairs: {{groups: {PAIR_GROUPS_FILE}}})"]
    write_csv(path, ["config", "group"], rows, comments)


def _mm(value: float | None) -> str:
    return "-" if value is None else f"{value * 1e3:.4f}"


def _sigma(info: Information) -> str:
    return f"{info.sigma_m * 1e3:g} mm" if info.unit == "m" else f"{info.sigma_m:g} {info.unit}"


def _markdown(result: PlanResult, plot: bool) -> str:
    info = result.info
    lines = [
        f"# Calibration plan: {result.cell}",
        "",
        f"{result.n} configurations of {result.robot} chosen from {len(result.candidates.q)} candidates "
        f"(seed {result.seed}) by the **{result.criterion}** criterion, for the {result.formulation} "
        f"formulation and model {result.model}.",
        "",
        *[f"- {line[0].upper()}{line[1:]}." for line in result.discarded_lines()],
        f"- Predicted position accuracy over the region: **{_mm(result.predicted_sigma_m)} mm RMS, the floor if the "
        f"model describes the robot** (scored point, {'no' if info.gauge == 'none' else info.gauge} gauge removed; "
        f"measurement sigma {_sigma(info)}); a "
        f"space-filling design of the same size: {_mm(result.space_filling_sigma_m)} mm.",
        f"- {result.prediction_lines()[1][0].upper()}{result.prediction_lines()[1][1:]}.",
        *([f"- {groups[0].upper()}{groups[1:]}."] if (groups := result.pair_groups_line()) else []),
        f"- {info.n_params} identifiable parameters: {', '.join(info.names)}.",
        f"- Auxiliary unknowns: {', '.join(info.aux_labels)}.",
        f"- Not identifiable from a design of this size: {', '.join(info.unidentifiable) or 'none'}.",
        "",
        "| index | value |",
        "|---|---|",
    ]
    for key, value in result.indices.items():
        lines.append(f"| {key} | {value:.4g} |")
    lines += [
        "",
        "Indices on the parameters' whitened Jacobian, columns scaled by plausible deviations (10 mm, "
        "10 mrad, compliances deflecting 10 mrad), auxiliary unknowns eliminated (docs/planning.md).",
        "",
        "## Predicted accuracy against the number of configurations (mm RMS)",
        "",
        "| N | planned (greedy) | random | space-filling |",
        "|---|---|---|---|",
    ]
    c = result.curves
    for i, size in enumerate(c["n"]):
        lines.append(
            f"| {size} | {_mm(c['planned_m'][i])} | {_mm(c['random_m'][i])} | {_mm(c['space_filling_m'][i])} |"
        )
    if plot:
        lines += ["", "![predicted accuracy](predicted_accuracy.png)"]
    lines += _approach_lines(result)
    t = result.timing_s
    lines += [
        "",
        f"CPU time: candidates {t.get('candidates', 0):.1f} s, information {t.get('information', 0):.1f} s, "
        f"selection {t.get('selection', 0):.1f} s, curves {t.get('curves', 0):.1f} s"
        + (f", pair groups {t['pair_groups']:.1f} s." if "pair_groups" in t else "."),
        "",
    ]
    return "\n".join(lines)


def _approach_lines(result: PlanResult) -> list[str]:
    lines = ["", "## Approach", ""]
    if result.approach == "unidirectional":
        lines.append(
            f"Every configuration is approached from {np.degrees(result.approach_offset_rad):.3g} deg below on every "
            "joint (configurations.csv `before_q1..`: move there first, then to the configuration). Its lost motion "
            "is then the same at every configuration, and the joint offsets absorb it: calibrate with DH,s,e, and "
            "run programs that approach their targets the same way."
        )
    elif result.approach == "varied":
        lines.append(
            f"Each configuration is approached from its own approach point, up to "
            f"{np.degrees(result.approach_offset_rad):.3g} deg above or below on each joint (configurations.csv "
            "`before_q1..`: move there first, then to the configuration): the direction and size of the last move "
            "vary, so that the lost motion and speed terms of model DH,s,e,h are identifiable; calibrate with it."
        )
    else:
        lines.append(
            "Each configuration is reached from the one before, in the plan's order (`--approach unidirectional` "
            "inserts approach points)."
        )
    lost = result.lost_motion
    if lost is None:
        lines += ["", "The cell declares no lost motion (motion_history): what the approach gains is not predicted."]
    else:
        lines += [
            "",
            "The cell's lost motion (motion_history) leaves at the scored point, beyond what constant joint offsets "
            f"absorb: **{_mm(lost['in_order_rms_m'])} mm RMS** visiting the plan in order, "
            f"**{_mm(lost['unidirectional_rms_m'])} mm** with each configuration approached from below. A static "
            "model (DH,s,e) cannot fit the first; model DH,s,e,h fits it from a plan in order.",
        ]
    return lines


def _plot(result: PlanResult, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    c = result.curves
    fig = Figure(figsize=(6.4, 4.2))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    sizes = np.array(c["n"])
    planned = [(s, v) for s, v in zip(sizes, c["planned_m"], strict=True) if v is not None]
    if planned:
        ax.plot(*zip(*[(s, v * 1e3) for s, v in planned], strict=True), "o-", label=f"planned ({result.criterion})")
    ax.plot(sizes, np.array(c["random_m"]) * 1e3, "s--", label=f"random (mean of {RANDOM_DRAWS})")
    ax.plot(sizes, np.array(c["space_filling_m"]) * 1e3, "^--", label="space-filling")
    ax.plot([result.n], [result.predicted_sigma_m * 1e3], "k*", markersize=12, label="this plan (after exchange)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("configurations N")
    ax.set_ylabel("predicted position sigma, RMS over the region (mm)")
    ax.set_title(f"{result.cell}: {result.formulation}, {result.model}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
