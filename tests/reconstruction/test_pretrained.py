"""Models shipped inside the package: exported from a run, loaded by name, encoding as the run did."""

import json

import pytest
import torch

from ushape.builders import build
from ushape.encoder.heads import ImageEncoder
from ushape.errors import InputError
from ushape.reconstruction import pretrained
from ushape.reconstruction.predictor import load_predictor


def test_an_exported_run_loads_by_name_and_encodes_as_the_run(tiny_run, tmp_path, monkeypatch):
    folder = pretrained.export_pretrained(tiny_run["run"], "tiny", tmp_path, category="chairs")
    assert sorted(p.name for p in folder.iterdir()) == [
        "MODEL_CARD.md",
        "decoder",
        "encoder.ckpt",
        "model.json",
        "splits.json",
    ]
    card = (folder / "MODEL_CARD.md").read_text()
    assert "# ushape model `tiny`" in card and "Category: chairs" in card and "research and non-commercial" in card
    assert json.loads((folder / "splits.json").read_text())["test"] == ["test_0", "test_1"]
    record = json.loads((folder / "model.json").read_text())
    assert record["name"] == "tiny" and record["category"] == "chairs" and record["image_size"] == 16
    latent = load_predictor(tiny_run["run"]).latent_size
    assert record["latent_size"] == latent and f"a Gaussian over the {latent}-d code" in card
    monkeypatch.setattr(pretrained, "PRETRAINED_DIR", tmp_path)
    assert pretrained.available_models() == ["tiny"]
    shipped, run = pretrained.load_pretrained("pretrained:tiny", temperature=False), load_predictor(tiny_run["run"])
    images = torch.rand(3, 3, 16, 16, generator=torch.Generator().manual_seed(1))
    (mu_a, var_a), (mu_b, var_b) = run.encode(images), shipped.encode(images)
    # fp16 storage of the weights: about 1e-3 relative
    scale = float(mu_a.abs().max().clamp(min=1.0))
    torch.testing.assert_close(mu_b, mu_a, rtol=0, atol=pretrained.EXPORT_TOLERANCE * scale)
    torch.testing.assert_close(var_b.log(), var_a.log(), rtol=0, atol=pretrained.EXPORT_TOLERANCE)
    with pytest.raises(FileNotFoundError, match="no shipped model 'sofas'; this installation has tiny"):
        pretrained.load_pretrained("sofas")


def test_an_exported_model_folder_outside_the_package_loads_by_its_path(tiny_run, tmp_path, monkeypatch):
    folder = pretrained.export_pretrained(tiny_run["run"], "candidate", tmp_path / "candidates", category="chairs")
    monkeypatch.setattr(pretrained, "PRETRAINED_DIR", tmp_path / "package")  # ships nothing
    assert pretrained.available_models() == [] and pretrained.model_dir(str(folder)) == folder
    assert pretrained.load_pretrained(str(folder)).model_name == str(folder)  # summary.json names the folder
    images = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(2))
    (mu_a, _), (mu_b, _) = (
        load_predictor(tiny_run["run"]).encode(images),
        pretrained.load_pretrained(str(folder)).encode(images),
    )
    torch.testing.assert_close(
        mu_b, mu_a, rtol=0, atol=pretrained.EXPORT_TOLERANCE * float(mu_a.abs().max().clamp(min=1.0))
    )
    with pytest.raises(FileNotFoundError, match="or give the path of an exported model folder"):
        pretrained.model_dir(str(tmp_path / "candidates"))  # a folder without model.json


def test_the_backbone_is_left_out_only_when_it_is_the_packages_frozen_imagenet_one():
    config = {
        "backbone": {"_target_": "ushape.encoder.backbones.efficientnet_lite0", "pretrained": True},
        "latent_size": 4,
        "freeze_backbone": True,
    }

    class Holder(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.encoder = build(config, ImageEncoder)

    model = Holder()
    assert pretrained.backbone_is_the_packages(model, config)
    with torch.no_grad():
        next(model.encoder.backbone.parameters()).add_(1e-3)
    assert not pretrained.backbone_is_the_packages(model, config)
    assert not pretrained.backbone_is_the_packages(Holder(), {**config, "freeze_backbone": False})


def test_a_model_file_that_does_not_fit_is_named(tiny_run, tmp_path):
    folder = pretrained.export_pretrained(tiny_run["run"], "tiny", tmp_path)
    blob = torch.load(folder / "encoder.ckpt", weights_only=False)
    blob["state_dict"]["encoder.head.extra"] = torch.zeros(1)
    torch.save(blob, folder / "encoder.ckpt")
    with pytest.raises(InputError, match="does not fit its model"):
        pretrained.load_model_folder(folder)


def test_a_records_update_rewrites_the_card_and_leaves_the_weights(tiny_run, tmp_path):
    folder = pretrained.export_pretrained(tiny_run["run"], "tiny", tmp_path, category="chairs")
    weights = (folder / "encoder.ckpt").read_bytes()
    merged = pretrained.update_record(folder, figures={"ceiling, 100 test shapes": "0.7"}, recipe="200 epochs")
    assert merged["name"] == "tiny" and json.loads((folder / "model.json").read_text()) == merged
    card = (folder / "MODEL_CARD.md").read_text()
    assert "| ceiling, 100 test shapes | 0.7 |" in card and "200 epochs" in card and "Not measured yet" not in card
    assert (folder / "encoder.ckpt").read_bytes() == weights


def test_exporting_the_same_run_again_keeps_its_recorded_figures_and_another_run_does_not(tiny_run, tmp_path):
    folder = pretrained.export_pretrained(tiny_run["run"], "tiny", tmp_path, category="chairs")
    pretrained.update_record(folder, figures={"ceiling": "0.7"}, recipe="200 epochs")
    again = json.loads((pretrained.export_pretrained(tiny_run["run"], "tiny", tmp_path) / "model.json").read_text())
    assert again["figures"] == {"ceiling": "0.7"} and again["recipe"] == "200 epochs" and again["category"] == "chairs"
    assert "| ceiling | 0.7 |" in (folder / "MODEL_CARD.md").read_text()
    checkpoint = str(tiny_run["run"] / "checkpoints" / "best.ckpt")
    other = json.loads((pretrained.export_pretrained(checkpoint, "tiny", tmp_path) / "model.json").read_text())
    assert "figures" not in other and "recipe" not in other
