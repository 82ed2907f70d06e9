"""Change what an exported pose model's card says about its category without touching its
weights (the card is the graph's metadata): the mirror planes, the defaults of fused runs,
verify, recheck and up, each with the measurement that justifies it.

    done = edit_card(Path("bed.onnx"), CardChanges(recommended_ensemble=8, ensemble_report=r))
    done.card.recommended_ensemble, done.written    # 8, bed.onnx
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import onnx

from itnet.export.card_config import CardChanges
from itnet.export.card_measurements import (
    anytime_evaluation,
    ensemble_evaluation,
    mirror_planes,
    switch_evaluation,
    up_evaluation,
    with_camera_views,
)
from itnet.export.onnx_export import save_with_card
from itnet.model.input_error import InputError
from itnet.model_card import (
    ModelCard,
    describe_mirror,
    describe_plan,
    describe_recheck,
    describe_verify,
)
from itnet.pose.runtime import ModelLoadError, load_any
from itnet.request_fields import parse_pair


@dataclass(frozen=True)
class CardReport:
    """The card after the changes, and the file it was written to (None: nothing changed,
    nothing written)."""

    card: ModelCard
    written: Path | None


def edit_card(model: Path, changes: CardChanges) -> CardReport:
    """Apply ``changes`` to ``model``'s card and write the model (to ``changes.out`` or in
    place) where the card changed. Raises ModelLoadError for a file that is not a pose model,
    InputError for a change without its measurement or a measurement that does not fit."""
    current = pose_card(model)
    changed = current.model_copy(update=card_update(current, changes))
    if changed == current:
        return CardReport(changed, None)
    target = changes.out or model
    return CardReport(changed, save_with_card(onnx.load(str(model)), changed, target))


def pose_card(model: Path) -> ModelCard:
    """The card of the pose model at ``model``; ModelLoadError for another kind of model (a
    classifier's or a verifier's card is written by its own export)."""
    card = load_any(model, warm_up=False).card
    if not isinstance(card, ModelCard):
        writer = "classify-export" if card.kind == "classifier" else "verifier-export"
        raise ModelLoadError(f"{model} is a {card.kind}; its card is written by {writer}")
    return card


def card_update(current: ModelCard, changes: CardChanges) -> dict[str, Any]:
    """The fields ``changes`` set on ``current``, each default checked against its
    measurement (given now or already on the card)."""
    update: dict[str, Any] = {}
    planes = mirror_planes(changes.mirror_planes, current.mirror_planes)
    if changes.mirror_planes is not None:
        update["mirror_planes"] = planes
    if changes.recommended_ensemble is not None:
        update["recommended_ensemble"] = changes.recommended_ensemble
        update["ensemble_evaluation"] = ensemble_evaluation(
            changes.recommended_ensemble, changes.ensemble_report
        )
    elif changes.ensemble_report is not None:
        raise InputError("--ensemble-report measures --recommended-ensemble: give both")
    if changes.mirror_fused is not None:
        if changes.mirror_fused and not planes:
            raise InputError("--mirror-fused needs mirror planes on the card")
        update["mirror_fused"] = changes.mirror_fused
    update |= switch_update(current, changes)
    if changes.report is not None:
        update["accuracy"], update["evaluation"] = anytime_evaluation(changes.report)
    update |= up_update(current, changes)
    update |= camera_update(current.model_copy(update=update), changes)
    if not planes:
        update["mirror_fused"] = False  # no planes: nothing to finish fused runs by
    return update


def switch_update(current: ModelCard, changes: CardChanges) -> dict[str, Any]:
    """The verify, recheck, mirror and plan measurements ``changes`` give, and the verify and
    recheck defaults and the schedule, each only with its measurement."""
    update: dict[str, Any] = {}
    for name, without, with_it, describe in (
        ("verify", changes.without_verify, changes.with_verify, describe_verify),
        ("recheck", changes.without_recheck, changes.with_recheck, describe_recheck),
        ("mirror", changes.without_mirror, changes.with_mirror, describe_mirror),
        ("plan", changes.without_plan, changes.with_plan, describe_plan),
    ):
        text = switch_evaluation(name, without, with_it, describe)
        if text is not None:
            update[f"{name}_evaluation"] = text
    runs = changes.recheck_runs
    if runs is not None:
        if runs and not (update.get("recheck_evaluation") or current.recheck_evaluation):
            raise InputError("--recheck-runs needs its measurement: --with-recheck")
        update["recheck_runs"] = runs
    if changes.verify_fused is not None:
        if changes.verify_fused and not (
            update.get("verify_evaluation") or current.verify_evaluation
        ):
            raise InputError("--verify-fused needs its measurement: --with-verify")
        update["verify_fused"] = changes.verify_fused
    measured = bool(update.get("plan_evaluation") or current.plan_evaluation)
    for name, text in (("coarse_steps", changes.coarse_steps), ("halving", changes.halving)):
        if text is not None:
            update[name] = _schedule(name, text, measured)
    return update


def _schedule(name: str, text: str, measured: bool) -> tuple[int, int] | None:
    """``--coarse-steps`` / ``--halving`` (two positive integers 'A,B', or 'none') -> the card's
    field; a schedule only with its measurement."""
    if text.strip().lower() == "none":
        return None
    option = "--" + name.replace("_", "-")
    try:
        pair = parse_pair(text)
    except ValueError:
        raise InputError(
            f"{option} takes two positive integers 'A,B' or 'none', got {text!r}"
        ) from None
    if not measured:
        raise InputError(f"{option} needs its measurement: --without-plan and --with-plan")
    return pair


def up_update(current: ModelCard, changes: CardChanges) -> dict[str, Any]:
    """The up measurement of the card's default runs, the steps run free before being held
    upright, and whether the model needs up (only with its measurement)."""
    update: dict[str, Any] = {}
    if changes.up_report is not None:
        runs = changes.recommended_ensemble or current.recommended_ensemble
        update["up_evaluation"] = up_evaluation(changes.up_report, runs)
    if changes.up_free_steps is not None:
        update["up_free_steps"] = changes.up_free_steps
    if changes.requires_up is not None:
        if changes.requires_up and not (changes.up_report or current.up_evaluation):
            raise InputError("--requires-up needs its measurement: --up-report")
        update["requires_up"] = changes.requires_up
    return update


def camera_update(card: ModelCard, changes: CardChanges) -> dict[str, Any]:
    """``--camera-report``'s views added to the card's served evaluation: ``up_evaluation``
    for a card that requires up, else ``ensemble_evaluation`` (a card of one run has none)."""
    if changes.camera_report is None:
        return {}
    field, kind = (
        ("up_evaluation", "up") if card.requires_up else ("ensemble_evaluation", "ensemble")
    )
    served = getattr(card, field)
    if not served:
        raise InputError(f"--camera-report: the card has no {field} to add the views to")
    runs = card.recommended_ensemble
    return {field: with_camera_views(served, kind, changes.camera_report, runs)}
