"""What a calibration config says about the measurements: their noise, robust losses and the
options of the formulations that read them (docs/calibration.md). Defined here, below the
formulations that use them; fgcal.calibration.config reads them (and the pipeline's own settings)
from a config that fgcal.calibration.schema has validated."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ..core.noise import NOISE

PARTNERS = ("other_object", "same_object", "same_side", "any")


@dataclass(frozen=True)
class Noise:
    """Declared standard deviations of the measurements (SI), per coordinate
    (fgcal.core.noise.NOISE says what each is); by default fgcal's, else what the dataset's
    instrument states, else what the config states."""

    camera_point_m: float = NOISE["camera_point_m"][2]
    tracker_m: float = NOISE["tracker_m"][2]
    pixel_px: float = NOISE["pixel_px"][2]
    touch_m: float = NOISE["touch_m"][2]
    spacing_m: float = NOISE["spacing_m"][2]
    pose_m: float = NOISE["pose_m"][2]
    pose_rad: float = NOISE["pose_rad"][2]
    distance_m: float = NOISE["distance_m"][2]
    contact_m: float = NOISE["contact_m"][2]

    @staticmethod
    def stated(*statements: dict[str, float]) -> Noise:
        """fgcal's defaults overridden by each statement in turn (later ones win)."""
        values: dict[str, float] = {}
        for statement in statements:
            values.update(statement)
        return Noise(**values)


# robust.* entry of each measurement kind and its default loss (threshold in robust sigmas).
# Cauchy for pixels: the influence of a gross false detection fades (Huber's stays k sigma).
ROBUST_DEFAULTS: dict[str, tuple[str, float] | None] = {
    "camera_points": None,
    "tracker_points": ("huber", 3.0),
    "touch_points": ("huber", 3.0),
    "tracker_poses": ("huber", 3.0),
    "distances": ("huber", 3.0),
    "contacts": ("huber", 3.0),
    "plane_contacts": ("huber", 3.0),
    "pixels": ("cauchy", 3.0),
    "tip_distances": ("huber", 3.0),
    "observed_pixels": ("cauchy", 3.0),
}


@dataclass(frozen=True)
class PairSettings:
    """How the relative formulation groups its images (fgcal.calibration.formulations.pairs)."""

    partner: str = "other_object"
    seed: int = 0
    group_images: int = 4
    points_from: str = "camera_points"  # or "pixels" (PnP per image)
    # pairs.groups: the file (resolved against the config) and its (config id, group label) rows in
    # the file's order; None: every image grouped at random.
    groups_file: Path | None = None
    groups: tuple[tuple[str, str], ...] | None = None
    groups_lines: tuple[int, ...] | None = None  # each row's line in the file (its comments counted)


@dataclass(frozen=True)
class MeasurementSettings:
    """Everything a formulation reads from the config; ``source`` names the config in errors."""

    source: Path = Path("<defaults>")
    noise: Noise = field(default_factory=Noise)  # in effect: defaults, the dataset's, the config's
    noise_stated: Mapping[str, float] = field(default_factory=dict)  # what the config states (SI)
    robust: Mapping[str, tuple[str, float] | None] = field(default_factory=lambda: dict(ROBUST_DEFAULTS))
    fixture_orientation: str = "known"  # pairs: the fixture's orientation in W known or estimated
    pairs: PairSettings = field(default_factory=PairSettings)
    # Camera intrinsics: None = fixed at the dataset's values; otherwise the prior sigmas (fx, fy,
    # cx, cy in px; k1, k2, p1, p2, k3) around them, from an earlier calibration.
    intrinsics_prior_sigmas: tuple[float, ...] | None = None
    # Tool points measured only by a separate validation set, declared on the flange (m).
    validation_tool_points: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
