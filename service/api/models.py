"""Request bodies: strict (a bool is not a number, a string is not a float), no extra fields."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class _Strict(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")


class ErrorOut(BaseModel):
    """What every refusal carries: why, in words (422s list the fields instead)."""

    detail: str | list[dict[str, Any]]


ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorOut, "description": why} for code, why in (
        (401, "no or an unknown X-API-Key"), (403, "the key's role is too low"),
        (404, "no such thing"), (409, "not possible in the present state"),
        (413, "too large"),
        (415, "a body of the wrong type (JSON with Content-Type: application/json; PNG for "
              "images)"), (422, "a malformed request"),
        (429, "too many wrong keys from this address: see Retry-After"),
        (503, "a part the request needs is not working"),
        (504, "the camera did not deliver in time"))}


class FeatureIn(_Strict):
    """Nominal diameter and tolerance of the feature being turned, mm."""

    nominal_mm: float = Field(gt=0, le=1000)
    tol_upper_mm: float = Field(ge=0, le=100)
    tol_lower_mm: float = Field(le=0, ge=-100)


class CompensationIn(_Strict):
    """Compensation tuning (see service/compensation/settings.py): the bands, the law and the
    limits; omitted fields keep their value."""

    window: int | None = Field(None, ge=1, le=1000)
    filter: Literal["median", "mean"] | None = None
    deadband_mm: float | None = Field(None, ge=0)
    gain: float | None = Field(None, gt=0, le=1)
    max_step_mm: float | None = Field(None, gt=0)
    max_total_mm: float | None = Field(None, gt=0)
    dead_time_measurements: int | None = Field(None, ge=0)
    dead_time_s: float | None = Field(None, ge=0)
    safe_area_mm: float | None = Field(None, gt=0)
    max_uncertainty_fraction: float | None = Field(None, gt=0, le=1)
    max_age_s: float | None = Field(None, gt=0)
    programming: Literal["diameter", "radius"] | None = None
    offset_sign: Literal[1, -1] | None = None
    law: Literal["window", "predictive"] | None = None
    trend_gain: float | None = Field(None, ge=0, lt=1)
    mean_value_band_mm: float | None = Field(None, ge=0)
    plausibility_mm: float | None = Field(None, gt=0)


class ShadowIn(_Strict):
    """Shadow mode on (compute, never write) or off."""

    shadow: bool


class CommandIn(_Strict):
    """A command to the compensation."""

    command: Literal["reset", "acknowledge", "insert_change"]
    tool: int | None = Field(None, ge=1, le=99999, description=(
        "one tool of a job of several tools (none: the compensation and every tool's); "
        "an insert change names its tool"))


class TemperatureIn(_Strict):
    """Part temperature (None: unknown, no 20 C correction)."""

    part_temp_c: float | None = Field(ge=-50, le=300)
    alpha_per_k: float | None = Field(None, ge=0, lt=1e-3)


class CalibrationImportIn(_Strict):
    """A calibration document in the interchange format, and why it is being imported."""

    document: dict[str, Any]
    note: str = Field("", max_length=2000)
    activate: bool = False


class SessionIn(_Strict):
    """A new session."""

    board: str = Field("11x8x8", description="COLSxROWSxMM: inner corners and square size")
    note: str = Field("", max_length=2000)


class ActivateIn(_Strict):
    """Import the built calibration and measure with it."""

    note: str = Field("", max_length=2000)


class JobIn(_Strict):
    """A job document (``service.compensation.job``: part number, name, features, tools),
    why it is added, and whether it is put in force at once."""

    document: dict[str, Any]
    note: str = Field("", max_length=2000)
    activate: bool = False


class FeatureSelectIn(_Strict):
    """The feature under the laser, by its number; null: recognised from the diameter."""

    feature: int | None = Field(ge=1, le=99)
