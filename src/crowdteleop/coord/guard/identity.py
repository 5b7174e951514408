"""Who a join link says the worker is: Prolific, MTurk-style, or nobody in particular."""

from __future__ import annotations

import re
from dataclasses import dataclass

from crowdteleop.coord.guard.errors import ApiError

EXTERNAL_ID = re.compile(r"^[A-Za-z0-9_.:-]{1,128}$")


@dataclass(frozen=True)
class Identity:
    source: str  # prolific | mturk | anonymous
    external_id: str | None = None
    study_id: str | None = None
    external_session: str | None = None


def _checked(params: dict[str, str], key: str, required: bool = False) -> str | None:
    value = params.get(key)
    if value is None or value == "":
        if required:
            raise ApiError(422, "invalid_request", f"{key} is required")
        return None
    if not EXTERNAL_ID.match(value):
        raise ApiError(422, "invalid_request", f"{key} must be 1-128 of A-Z a-z 0-9 _ . : -")
    return value


def identify(params: dict[str, str]) -> Identity:
    """Prolific (PROLIFIC_PID, STUDY_ID, SESSION_ID) first, then MTurk (workerId, hitId,
    assignmentId); without either, an anonymous worker (a new one per join)."""
    if "PROLIFIC_PID" in params:
        return Identity(
            "prolific",
            _checked(params, "PROLIFIC_PID", required=True),
            _checked(params, "STUDY_ID"),
            _checked(params, "SESSION_ID"),
        )
    if "workerId" in params:
        return Identity(
            "mturk",
            _checked(params, "workerId", required=True),
            _checked(params, "hitId"),
            _checked(params, "assignmentId"),
        )
    return Identity("anonymous")
