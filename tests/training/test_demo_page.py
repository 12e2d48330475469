"""The demo's page: its held-out shape from one view and from all, fused and refined, in one report.html."""

import json
import shutil

import torch
from analytic_decoder import EllipsoidDecoder

from ushape import atomic
from ushape.data.layout import WorldIndex, read_split
from ushape.decoder.artifacts import DECODER_FILE, save_decoder
from ushape.training.demo_meshes import write_demo_meshes

LATENT = 8


def test_the_demo_writes_one_page_with_every_view_count_and_mode(tiny_run, tmp_path):
    decoder_dir = shutil.copytree(tiny_run["decoder_dir"], tmp_path / "decoder")
    save_decoder(
        decoder_dir / DECODER_FILE,
        EllipsoidDecoder(latent_size=LATENT),
        {"_target_": "analytic_decoder.EllipsoidDecoder", "latent_size": LATENT},
    )
    run = shutil.copytree(tiny_run["run"], tmp_path / "run")
    checkpoint = run / "checkpoints" / "best.ckpt"
    blob = torch.load(checkpoint, map_location="cpu", weights_only=False)
    blob["hyper_parameters"]["decoder_path"] = str(decoder_dir)
    torch.save(blob, checkpoint)
    record = json.loads((run / "run.json").read_text())
    atomic.write_json(
        run / "run.json", {**record, "decoder_dir": str(decoder_dir), "encoder_checkpoint": str(checkpoint)}
    )
    root = tiny_run["world"]
    world = WorldIndex(root, "chairs", {s: read_split(root, s) for s in ("train", "val", "test")})
    out = write_demo_meshes(run, world, tmp_path / "meshes", resolution=24, split="test", refine="masks")
    page = (out / "report.html").read_text()
    labels = ["1 view, fused", "1 view, refined", "3 views, fused", "3 views, refined"]
    positions = [page.index(f'"label": "{label}"') for label in labels]
    assert positions == sorted(positions)  # one view first, fused before refined
    assert (out / "model-viewer-umd.min.js").is_file() and (out / "demo_colourbar.png").is_file()
