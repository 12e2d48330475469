"""Gathering an evaluation sweep's rows into one table."""

import json

import pytest

from ushape.evaluation.gather import gather, gather_rows, main


def _job(sweep, name, overrides, rows):
    folder = sweep / name
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    (folder / "eval_row.json").write_text(json.dumps(rows))


def _row(label, fusion, scale, iou):
    return {
        "encoder": label.lower(),
        "label": label,
        "fusion": fusion,
        "min_scale": scale,
        "single_view_iou": 0.3,
        "multi_view_iou": iou,
        "n_views": 8,
        "n_instances": 2,
    }


def test_gather_orders_jobs_numerically_and_keeps_their_overrides(tmp_path, capsys):
    _job(tmp_path, "10_fusion.k=10", ["fusion=bayesian_k", "fusion.k=10"], [_row("Ours", "bayesian-10", 1.0, 0.5)])
    _job(
        tmp_path,
        "2_fusion.k=2",
        ["fusion=bayesian_k", "fusion.k=2", "runs=[/a,/b]"],
        [_row("Ours", "bayesian-2", 1.0, 0.6), _row("FroDO*", "bayesian-2", 1.0, None)],
    )
    rows = gather_rows(tmp_path)
    assert [(r["job"], r["label"]) for r in rows] == [
        ("2_fusion.k=2", "Ours"),
        ("2_fusion.k=2", "FroDO*"),
        ("10_fusion.k=10", "Ours"),
    ]
    assert rows[0]["overrides"] == "fusion=bayesian_k fusion.k=2"
    markdown = gather(tmp_path).read_text()
    assert "| 2_fusion.k=2 | fusion=bayesian_k fusion.k=2 | Ours | bayesian-2 | 1.0000 | 0.3000 | 0.6000 |" in markdown
    assert "| – |" in markdown  # a missing number
    assert (tmp_path / "gathered.csv").read_text().splitlines()[0].startswith("job,overrides,encoder")
    main([str(tmp_path)])
    assert "gathered.md" in capsys.readouterr().out


def test_gather_explains_a_folder_without_rows(tmp_path):
    (tmp_path / "0_loss=es").mkdir()
    with pytest.raises(FileNotFoundError, match="evaluation sweep"):
        gather_rows(tmp_path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        gather_rows(tmp_path / "missing")
