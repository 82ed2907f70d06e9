"""``GET /v1/models``, ``/healthz`` (alive), ``/readyz`` (a model is loaded), ``/metrics``."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse

from itnet.pose.recognition import pose_model_for
from itnet.pose.runtime import LoadedClassifier, LoadedModel
from itnet.service.api.deps import StateDep
from itnet.service.schemas import (
    CARD_KEPT_IN_FILE,
    AutoInfo,
    Health,
    ModelInfo,
    ModelsResponse,
    Readiness,
    UprightClassifierInfo,
)

router = APIRouter(tags=["system"])


def model_info(name: str, model: LoadedModel, default: bool) -> ModelInfo:
    """What ``GET /v1/models`` says of a model: its card's fields (but those the file keeps to
    itself), and what this server knows beside the card (the corrections and verifier loaded,
    the step time)."""
    return ModelInfo(
        **model.card.model_dump(exclude=CARD_KEPT_IN_FILE | {"name"}),  # served by its name
        mirror=model.card.mirror,
        name=name,
        verifier=None if model.verifier is None else model.verifier.card.name,
        centre=model.centre is not None,
        centre_viewpoint=model.centre_viewpoint is not None,
        centre_up=model.centre_up is not None,
        centre_up_viewpoint=model.centre_up_viewpoint is not None,
        step_ms=round(model.step_ms, 3),
        default=default,
    )


@router.get("/v1/models", response_model=ModelsResponse, summary="The loaded models")
async def models(state: StateDep) -> ModelsResponse:
    """Each loaded model with its category, point count, trained iterations and measured accuracy
    (from the card inside the model file), and this server's measured step time."""
    default = state.default_model_name()
    infos = [model_info(name, m, name == default) for name, m in sorted(state.models.items())]
    auto = None
    if state.classifier is not None:
        card = state.classifier.card
        picks = {c: pose_model_for(c, state.models) for c in card.classes}
        auto = AutoInfo(
            classes=card.classes,
            threshold=card.threshold,
            accuracy=card.accuracy,
            mean_class_accuracy=card.mean_class_accuracy,
            points=card.points,
            evaluation=card.evaluation,
            second_looks=state.settings.classify_second_looks,
            cascade=card.cascade,
            models={c: None if m is None else m.card.name for c, m in picks.items()},
            sizes=None if card.size_prior is None else card.size_prior.evaluation,
            upright=_upright_info(state.classifier.upright),
        )
    return ModelsResponse(models=infos, default_model=default if state.ready else None, auto=auto)


@router.get("/healthz", response_model=Health, summary="Liveness: the process serves HTTP")
async def healthz() -> Health:
    return Health()


@router.get(
    "/readyz",
    response_model=Readiness,
    responses={503: {"model": Readiness, "description": "no model loaded"}},
    summary="Readiness: a model is loaded and estimates can be served",
)
async def readyz(state: StateDep) -> JSONResponse:
    body = Readiness(ready=state.ready, models=sorted(state.models), detail=state.load_error)
    return JSONResponse(body.model_dump(), status_code=200 if state.ready else 503)


@router.get(
    "/metrics",
    summary="Prometheus metrics (text exposition format)",
    response_class=Response,
    responses={200: {"content": {"text/plain": {}}}},
)
async def metrics(state: StateDep) -> Response:
    return Response(state.metrics.render(), media_type=state.metrics.content_type)


def _upright_info(classifier: LoadedClassifier | None) -> UprightClassifierInfo | None:
    if classifier is None:
        return None
    card = classifier.card
    return UprightClassifierInfo(
        threshold=card.threshold,
        accuracy=card.accuracy,
        mean_class_accuracy=card.mean_class_accuracy,
        evaluation=card.evaluation,
        sizes=None if card.size_prior is None else card.size_prior.evaluation,
    )
