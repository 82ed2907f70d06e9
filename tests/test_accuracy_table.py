"""The README's accuracy table is rendered from the shipped cards' measurements."""

from __future__ import annotations

from pathlib import Path

from itnet.accuracy_table import HEADER, accuracy_table
from itnet.measurements import Measurement, ViewResult
from itnet.model_card import ModelCard
from itnet.pose.runtime import LoadedModel, default_model_dir, load_any
from itnet.service.api.routes.system import model_info

README = Path(__file__).resolve().parents[1] / "README.md"


def _shipped() -> list:
    infos = []
    for path in sorted(default_model_dir().glob("*.onnx")):
        loaded = load_any(path, warm_up=False)
        if isinstance(loaded, LoadedModel):
            infos.append(model_info(loaded.card.name, loaded, False))
    return infos


def test_the_readme_shows_the_table_the_cards_render():
    rows = accuracy_table(_shipped())
    assert rows[0] == HEADER and len(rows) == 2 + 10  # every category's own model, no other
    text = README.read_text()
    start = text.index(HEADER)
    assert text[start:].splitlines()[: len(rows)] == rows


def test_a_row_takes_the_served_measurement_and_the_paper_views_with_up():
    def line(kind: str, paper: float) -> str:
        rows = [ViewResult(views=v, runs=8, scans=100, accuracy=a, before=a - 1, gain=1.0,
                           gain_stderr=0.5, stderr=1.0)
                for v, a in (("occluded", 60.0), ("surface", 70.0), ("paper", paper))]  # fmt: skip
        return Measurement(kind=kind, split="test", budget_ms=50, machine="m", results=rows,  # type: ignore[arg-type]
                           up_error_deg=2.0 if kind == "up" else None).text()  # fmt: skip

    card = ModelCard(name="table", category="table", symmetry="yaw180", recommended_ensemble=8,
                     ensemble_evaluation=line("ensemble", 80.0), up_evaluation=line("up", 90.0))  # fmt: skip
    loaded = load_any(default_model_dir() / "table.onnx", warm_up=False)
    assert isinstance(loaded, LoadedModel)
    loaded.card, loaded.centre_viewpoint, loaded.centre_up_viewpoint = card, None, None
    info = model_info("table", loaded, False)
    assert accuracy_table([info])[2] == (
        "| table | yaw180 | 8 | – | **60.0%** | 70.0% | **80.0%** | 90.0% | – |"
    )  # no views by a depth camera measured: a dash
    camera = ViewResult(views="occluded+kinect_v2", runs=8, scans=100, accuracy=45.5, before=44.0,
                        gain=1.5, gain_stderr=0.5)  # fmt: skip
    served = Measurement.parse("ensemble", card.ensemble_evaluation)
    card.ensemble_evaluation = served.model_copy(
        update={"results": [camera, *served.results]}
    ).text()
    info = model_info("table", loaded, False)
    assert accuracy_table([info])[2] == (
        "| table | yaw180 | 8 | **45.5%** | **60.0%** | 70.0% | **80.0%** | 90.0% | – |"
    )
