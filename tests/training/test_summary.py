"""The lines a run ends with: where everything went, the demo reconstructions, and what to run next."""

import json

from ushape.training.demo_meshes import demo_digest
from ushape.training.summary import print_summary


def _demo(folder, views, trace, std):
    folder.mkdir(parents=True)
    record = {
        "views": [{}] * views,
        "fused": {"trace_var": trace},
        "mesh": {"std_mean": std},
        "files": {"overview": str(folder / "overview.png")},
    }
    (folder / "summary.json").write_text(json.dumps(record))


def test_the_demo_is_summarised_one_view_first_and_an_empty_surface_said(tmp_path):
    _demo(tmp_path / "meshes" / "s_12views", 12, 0.04, 0.0065)
    _demo(tmp_path / "meshes" / "s_1view", 1, 0.52, 0.024)
    (tmp_path / "meshes" / "t_1view").mkdir()  # no surface: only its note
    rows = demo_digest(tmp_path / "meshes")
    assert [r["name"] for r in rows] == ["t_1view", "s_1view", "s_12views"]
    assert rows[0] == {"name": "t_1view", "empty": True} and rows[1]["trace"] == 0.52


def test_the_summary_prints_brackets_and_the_next_commands(tmp_path, capsys):
    _demo(tmp_path / "meshes" / "s_1view", 1, 0.52, 0.024)
    print_summary({"encoder_checkpoint": "ckpt", "demo": demo_digest(tmp_path / "meshes")}, tmp_path)
    out = capsys.readouterr().out
    assert "1 view(s), latent trace 0.520, mean vertex std 0.0240" in out
    assert f"python eval.py runs=[{tmp_path}]" in out and "python reconstruct.py" in out
