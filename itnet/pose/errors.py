"""Why the pose pipeline refuses a request: one exception class per kind, each with its status.

``kind`` is the machine-readable label (a reply's ``kind``, a metrics label); ``status`` the HTTP
status the service answers with (the CLI exits 2 for any of them). The library raises these; the
service maps them onto its replies in one place (``itnet.service.errors``).
"""

from __future__ import annotations


class PoseError(ValueError):
    """A request the pipeline refuses; the message says what is wrong in one sentence."""

    kind = "invalid_request"
    status = 422


class BadCloudError(PoseError):
    """The cloud cannot be used: wrong shape, non-finite values, too few/many points, degenerate,
    or an option that does not fit it (a bad ``up``, ``viewpoint`` or finishing stage)."""

    kind = "bad_cloud"


class UnknownModelError(PoseError):
    kind = "unknown_model"
    status = 404


class NoClassifierError(PoseError):
    """``model: "auto"`` without a category classifier loaded."""

    kind = "no_classifier"


class NoPoseModelError(PoseError):
    """``model: "auto"`` recognised a category that has no pose model loaded."""

    kind = "no_pose_model"


class BudgetTooSmallError(PoseError):
    """Not even one step fits the budget on an idle machine: no pose can be served."""

    kind = "budget_too_small"


class OverloadedError(PoseError):
    """The work already admitted leaves no room for this request's first step inside its budget
    (retry after ``retry_after_s``), or none fit after all: never an identity served as a pose."""

    kind = "overloaded"
    status = 503

    def __init__(self, message: str, retry_after_s: int = 1) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s
