"""The schema of an online setup file (fgcal online --setup; docs/online.md); service.load_config
validates a setup here first, then resolves its paths and checks its parameter names."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from ..calibration.formulations import NAMES
from ..core.schema import Number, Schema
from ..model.robot import MODELS
from ..model.schema import RobotReference


class Settings(Schema):
    """The online calibration's settings (SI; per-cycle sigmas of the random walk)."""

    pixel_sigma_px: Number = Field(None, gt=0, description="px (default 0.1)")
    prior_sigma_m: Number = Field(None, gt=0, description="m (default 5e-3)")
    prior_sigma_rad: Number = Field(None, gt=0, description="rad (default 5e-3)")
    prior_sigma_compliance: Number = Field(None, gt=0, description="rad/(N m) (default 1e-4 with formulation, "
                                         "1e-6 for a flange camera's images)")  # fmt: skip
    drift_sigma_m: Number = Field(None, gt=0, description="m per cycle (default 1e-6)")
    drift_sigma_rad: Number = Field(None, gt=0, description="rad per cycle (default 1e-6)")
    drift_sigma_compliance: Number = Field(None, gt=0, description="rad/(N m) per cycle (default 1e-10)")
    window_images: int = Field(None, ge=1, description="images in the window (default 20; at least twice "
                               "marginalise_every)")  # fmt: skip
    marginalise_every: int = Field(None, ge=1, description="images leave the window in blocks (default 5)")
    alarm_lag_images: int = Field(None, ge=1, description="default 5")
    alarm_false_rate: Number = Field(None, gt=0, description="per image, over all parameters (default 1e-3)")
    outlier_gate_px: Number = Field(None, gt=0, description="px (default 3)")
    outlier_gate_sigma: Number = Field(None, gt=0, description="a formulation's measurement whose residual at the "
                                       "current estimate exceeds this many predicted sigmas is not folded in "
                                       "(default 5, docs/online.md)")  # fmt: skip
    gate_run: int = Field(None, ge=2, description="this many consecutive gated configurations are a change of the "
                          "robot: a drift alarm, and they are folded in (default 3)")  # fmt: skip
    determined_fraction: Number = Field(None, gt=0, description="with formulation and no released list: "
                                        "a geometric parameter (m, rad) is released when its sigma at the "
                                        "reference data's solution is at most this fraction of its prior sigma "
                                        "(default 0.05)")  # fmt: skip
    start_measurements: int = Field(None, ge=1, description="measurements held back and folded in together before "
                                    "the first update, a formulation's (default 10)")  # fmt: skip
    compliant_joints: list[int] = Field(None, description="1-based joints with a compliance (default 1-3)")
    relinearize_fraction: Number = Field(None, gt=0, description="of a prior sigma (default 0.1)")
    relinearize_pose: Number = Field(None, gt=0, description="rad, m (default 1e-4)")


class OnlineSetup(Schema):
    """An online setup (fgcal online --setup)."""

    dataset: str = Field(description="the calibration's dataset folder, relative to the setup")
    formulation: Literal[NAMES] = Field(None, description="what the inbox's files measure, any registered "
                                         "formulation's (fgcal.online.protocol); absent: a flange camera's images")
    model: Literal[MODELS] = Field(None, description="the model refined online, with formulation (default: the "
                                   "dataset's robot's)")
    robot: RobotReference = None
    released: list[str] = Field(None, description="the parameters recalibrated online (default: the calibration's)")
    settings: Settings = None
    target_accuracy_m: Number = Field(5e-5, gt=0, description="m")
