"""Every category's evaluation in one table and one plot."""

import json

from itnet.model.category_report import load_reports, table, write_report


def _report(accuracy, symmetry, scans=40):
    k = list(range(len(accuracy)))
    return {"iterations": k, "accuracy": accuracy, "rotation_accuracy": accuracy,
            "translation_accuracy": [1.0] * len(k), "median_rotation_deg": [5.0] * len(k),
            "median_translation": [0.05] * len(k), "scans": scans, "symmetry": symmetry,
            "orientation": {"kept": 9, "turned": 1, "dropped": 0}}  # fmt: skip


def test_table_and_plot_cover_every_evaluated_category(tmp_path):
    evals, out = tmp_path / "evals", tmp_path / "docs"
    out.mkdir()
    curves = {"sofa": ([0.0] + [0.5] * 20, "none"), "table": ([0.0] + [0.75] * 20, "yaw180")}
    for name, (acc, sym) in curves.items():
        for scanner in ("occluded", "paper"):
            folder = evals / name / scanner
            folder.mkdir(parents=True)
            (folder / "report.json").write_text(json.dumps(_report(acc, sym)))
    (evals / "half_done" / "occluded").mkdir(parents=True)  # no paper views yet: left out
    (evals / "half_done" / "occluded" / "report.json").write_text(
        json.dumps(_report([0.1], "none"))
    )
    assert sorted(load_reports(evals)) == ["sofa", "table"]
    write_report(evals, out)
    text = (out / "eval_categories.md").read_text()
    assert "| sofa | none | 9 / 1 / 0 | 40 | **50.0** ± 7.9 |" in text
    assert "| table | yaw180 |" in text and "**75.0** ± 6.8" in text
    assert (out / "anytime_categories.png").stat().st_size > 10_000
    assert "sofa" in json.loads((out / "eval_categories.json").read_text())
    assert table(load_reports(evals)).count("\n") == 4  # header, rule, two rows
    assert "| 0.050 | – | **50.0**" in text  # no surface views measured: a dash


def test_surface_views_get_their_column_and_panel_where_measured(tmp_path):
    evals, out = tmp_path / "evals", tmp_path / "docs"
    out.mkdir()
    for scanner, acc in (("occluded", 0.5), ("surface", 0.625), ("paper", 0.75)):
        folder = evals / "toilet" / scanner
        folder.mkdir(parents=True)
        (folder / "report.json").write_text(json.dumps(_report([0.0] + [acc] * 20, "none")))
    (evals / "sofa" / "occluded").mkdir(parents=True)  # a category without surface views
    (evals / "sofa" / "paper").mkdir(parents=True)
    for scanner in ("occluded", "paper"):
        (evals / "sofa" / scanner / "report.json").write_text(
            json.dumps(_report([0.2] * 21, "none"))
        )
    reports = load_reports(evals)
    assert set(reports["toilet"]) == {"occluded", "surface", "paper"}
    assert set(reports["sofa"]) == {"occluded", "paper"}
    write_report(evals, out)
    text = (out / "eval_categories.md").read_text()
    assert "| 0.050 | **62.5** ± 7.7 | **75.0** ± 6.8 |" in text
    assert "| sofa |" in text and "| – | **20.0**" in text
