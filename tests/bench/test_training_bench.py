"""bench.py --training: every row is timed and printed against its floor (no time is asserted)."""

from ushape.bench.training import (
    TrainingSettings,
    bf16_rows_in_full,
    machine,
    training_report,
    training_rows,
    write_training_report,
)

TINY = TrainingSettings(
    shapes=8,
    shapes_per_batch=4,
    samples_per_shape=64,
    steps=2,
    warmup=1,
    latent_codes=2,
    latent_iterations=3,
    latent_samples=100,
    feature_views=2,
    threads=(1,),
    world_shapes=1,
    world_workers=(1, 2),
    world_samples=1000,
    world_views=1,
    world_image_size=32,
    world_mesh_resolution=32,
)


def test_every_row_is_timed_at_each_precision_and_written(tmp_path):
    rows = training_rows(TINY)
    names = {(r.name, r.precision) for r in rows}
    fp32 = {
        "world build (procedural chairs)",
        "gemm (one decoder layer)",
        "stage-1 bare loop",
        "stage-1 Lightning step",
        "stage-1 loader alone",
        "latent optimisation",
        "feature extraction (Lite0, 128 px)",
    }
    assert {(name, "fp32") for name in fp32} <= names
    bf16_full = fp32 - {"stage-1 loader alone", "world build (procedural chairs)"}
    bf16 = bf16_full if bf16_rows_in_full() else {"gemm (one decoder layer)", "stage-1 bare loop"}
    assert {n for n, p in names if p == "bf16"} == bf16
    worlds = [r for r in rows if r.name == "world build (procedural chairs)"]
    assert [r.threads for r in worlds] == [1, 2] and worlds[0].ratio is None and worlds[1].floor == "1 worker / 2"
    assert all(r.rate > 0 for r in rows) and all(r.threads == 1 for r in rows if r not in worlds)
    step = next(r for r in rows if r.name == "stage-1 Lightning step" and r.precision == "fp32")
    assert step.floor == "bare loop" and step.ratio > 0
    about = machine()
    report = training_report(rows, about)
    assert about["cpu"] in report and "precision auto picks" in report and report.count("\n|") == len(rows) + 2
    write_training_report(rows, about, tmp_path / "training.md")
    assert (tmp_path / "training.md").read_text() == report and (tmp_path / "training.json").is_file()
