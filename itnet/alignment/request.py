"""``AlignRequest``: what an alignment asks for, declared once for ``POST /v1/align``, the clients,
``itnet-align`` and ``itnet batch align``.

    request = AlignRequest(model="chair", budget_ms=100)
    request.pose_request()          # the PoseRequest each cloud's pose is planned from
    request.options(card, refine)   # the knobs of itnet.alignment.pipeline.align_clouds
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from numpy.typing import ArrayLike
from pydantic import ConfigDict, Field

from itnet.pose.request import PoseRequest
from itnet.request_fields import RequestModel, Xyz
from itnet.size_prior import Unit

if TYPE_CHECKING:
    from itnet.alignment.pipeline import AlignOptions
    from itnet.model_card import ModelCard

SYMMETRY_CHOICES = ("auto", "none", "yaw180", "yaw90", "yaw")
DEFAULT_BUDGET_MS = 100.0


class AlignRequest(RequestModel):
    """How to align cloud A onto cloud B (the clouds travel beside it)."""

    model_config = ConfigDict(extra="forbid", protected_namespaces=())
    CLI_DEFAULTS: ClassVar[dict[str, Any]] = {"model": "chair"}  # a command line names its model
    CLI_ALIASES: ClassVar[dict[str, tuple[str, ...]]] = {"starts": ("--ensemble",)}

    model: str | None = Field(default=None, description="model name (default: the server's)")
    budget_ms: float = Field(
        default=DEFAULT_BUDGET_MS,
        gt=0,
        description="time budget of the whole alignment, ms: both clouds' poses and the choice "
        "between the hypotheses",
    )
    max_iterations: int | None = Field(
        default=None, ge=1, description="iteration cap of each pose (default: the model's)"
    )
    starts: int | None = Field(
        default=None,
        ge=1,
        le=16,
        description="runs fused into each cloud's pose (default: the alignment's 4)",
    )
    refine: bool | None = Field(
        default=None, description="ICP after IT-Net (default: when open3d is installed)"
    )
    symmetry: str = Field(
        default="auto",
        pattern=f"^({'|'.join(SYMMETRY_CHOICES)})$",
        description="symmetry turns tried as rivals: auto (the model's category and card), "
        "none, yaw180, yaw90, yaw",
    )
    rivals: bool | None = Field(
        default=None,
        description="judge rivals (other runs' poses, symmetric turns) where the composed pose "
        "is in doubt; false: the composed pose, refined with refine, only (default: where ICP "
        "refines them; unrefined rivals replace a right composed pose about as often as a "
        "wrong one)",
    )
    candidates: int = Field(
        default=6,
        ge=1,
        le=64,
        description="distinct rivals judged where the composed pose is in doubt",
    )
    finalists: int = Field(
        default=3, ge=1, le=64, description="rivals that get ICP's fine stage (with refine)"
    )
    sweep: int = Field(
        default=24,
        ge=0,
        le=72,
        description="where both ups are given: turns about up tried from the composed pose, "
        "each refined by ICP while the budget allows (0: none)",
    )
    up_a: Xyz = Field(
        default=None,
        description="which way is up in cloud A, [x, y, z] (against gravity): its poses are held "
        "upright and its runs start from turns about it. Needed by models that require up",
    )
    up_b: Xyz = Field(default=None, description="which way is up in cloud B, [x, y, z]")
    viewpoint: Xyz = Field(
        default=None,
        description="where the sensor was in both clouds' frames, [x, y, z]: each pose's centre "
        "is finished by it",
    )
    units: Unit | None = Field(
        default=None, description=PoseRequest.model_fields["units"].description
    )

    def body(self, points_a: ArrayLike, points_b: ArrayLike) -> dict:
        """The JSON body of ``POST /v1/align``: the clouds (N, 3), (M, 3) and the fields set."""
        from itnet.clients.wire import as_cloud

        return {"points_a": as_cloud(points_a).tolist(), "points_b": as_cloud(points_b).tolist(),
                **self.model_dump(exclude_defaults=True), "budget_ms": self.budget_ms}  # fmt: skip

    def pose_request(self, model: str | None = None) -> PoseRequest:
        """The request each cloud's pose is planned from (``model``: the resolved name), before
        ``itnet.alignment.estimators.cloud_request`` gives it its share of the budget."""
        return PoseRequest(budget_ms=self.budget_ms, max_iterations=self.max_iterations,
                           model=model or self.model, ensemble=self.starts,
                           viewpoint=self.viewpoint, units=self.units)  # fmt: skip

    def options(self, card: ModelCard, refine: bool) -> AlignOptions:
        """The alignment's knobs on the model of ``card``: its symmetry turns where ``auto``."""
        from itnet.alignment.hypotheses import rival_turns
        from itnet.alignment.pipeline import AlignOptions

        symmetry = self.symmetry
        if symmetry == "auto":
            symmetry = rival_turns(card.category, card.symmetry)
        return AlignOptions(symmetry=symmetry, refine=refine, budget_ms=self.budget_ms,
                            rivals=refine if self.rivals is None else self.rivals,
                            candidates=self.candidates, finalists=self.finalists,
                            sweep=self.sweep)  # fmt: skip
