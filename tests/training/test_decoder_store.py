"""The stage-1 decoder is trained once per identity and reused, also under concurrent runs."""

import multiprocessing as mp
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tiny_render_world import tiny_decoder_config

from ushape.decoder.artifacts import DECODER_FILE, DONE_FILE, CodeTable, codes_file, save_codes, save_decoder
from ushape.decoder.network import DeepSDFDecoder
from ushape.training.decoder_store import decoder_dir_for, ensure_decoder


def _cfg(tmp_path: Path, **over):
    cfg = OmegaConf.create(
        {
            "seed": 1,
            "category": {"name": "chairs"},
            "data": {
                "_target_": "ushape.data.world.SyntheticWorld",
                "n_train": 4,
                "num_workers": 0,
                "root": str(tmp_path / "data"),
            },
            "decoder": {"_target_": "x", "hidden_dims": [8]},
            "stage1": {"epochs": 3},
            "paths": {"decoders_dir": str(tmp_path / "decoders")},
            "loss": {"_target_": "es"},
        }
    )
    return OmegaConf.merge(cfg, OmegaConf.create(over))


def _fake_train(folder: Path, log: Path | None = None, delay: float = 0.0):
    time.sleep(delay)
    if log is not None:
        with open(log, "a") as fh:
            fh.write("trained\n")
    _write_artifacts(folder)
    (folder / DONE_FILE).write_text("ok")


def _write_artifacts(folder: Path) -> None:
    """What stage 1 leaves: a (tiny, random) decoder and the three code tables; the store checks they load."""
    config = tiny_decoder_config(4)
    save_decoder(folder / DECODER_FILE, DeepSDFDecoder(**{k: v for k, v in config.items() if k != "_target_"}), config)
    for split in ("train", "val", "test"):
        save_codes(folder / codes_file(split), CodeTable([f"{split}_0"], torch.zeros(1, 4)))


def test_reuse_and_identity(tmp_path):
    calls = []
    cfg = _cfg(tmp_path)
    first = ensure_decoder(cfg, lambda d: (calls.append(d), _fake_train(d)))
    again = ensure_decoder(_cfg(tmp_path, loss={"_target_": "nll"}, data={"num_workers": 2}), lambda d: calls.append(d))
    assert first == again and len(calls) == 1  # loss and worker count do not change the decoder
    other = decoder_dir_for(_cfg(tmp_path, decoder={"hidden_dims": [16]}))
    assert other != first
    assert decoder_dir_for(_cfg(tmp_path, category={"name": "tables"})) != first
    # The synthetic world's cache location does not change it; a real dataset's root does.
    assert decoder_dir_for(_cfg(tmp_path, data={"root": "/elsewhere"})) == first
    real = {"_target_": "ushape.data.real.shapenet_world.ShapeNetWorld", "root": "/data/a"}
    assert decoder_dir_for(_cfg(tmp_path, data=real)) != decoder_dir_for(
        _cfg(tmp_path, data={**real, "root": "/data/b"})
    )


def test_unfinished_training_is_an_error_not_a_reusable_folder(tmp_path):
    cfg = _cfg(tmp_path)
    try:
        ensure_decoder(cfg, lambda d: None)
    except RuntimeError as err:
        assert DONE_FILE in str(err)
    else:
        raise AssertionError("expected RuntimeError")
    calls = []
    ensure_decoder(cfg, lambda d: (calls.append(1), _fake_train(d)))
    assert calls == [1]


def _worker(tmp: str, log: str):
    ensure_decoder(_cfg(Path(tmp)), lambda d: _fake_train(d, Path(log), delay=1.0))


def test_two_concurrent_runs_train_once(tmp_path):
    log = tmp_path / "log.txt"
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_worker, args=(str(tmp_path), str(log))) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    assert log.read_text().count("trained") == 1


def test_stage1_worker_count_does_not_retrain_the_decoder(tmp_path):
    """stage1.data.num_workers used to be hashed with the rest of stage1: changing it trained stage 1 again."""
    stage1 = {"epochs": 3, "data": {"samples_per_shape": 64, "num_workers": 4}}
    calls = []
    first = ensure_decoder(_cfg(tmp_path, stage1=stage1), lambda d: (calls.append(d), _fake_train(d)))
    fewer = _cfg(tmp_path, stage1={"epochs": 3, "data": {"samples_per_shape": 64, "num_workers": 0}})
    assert ensure_decoder(fewer, lambda d: calls.append(d)) == first and len(calls) == 1
    assert decoder_dir_for(_cfg(tmp_path, stage1={"epochs": 3, "data": {"samples_per_shape": 32}})) != first


def test_decoders_named_by_the_older_identity_are_still_found(tmp_path):
    """A decoder trained when the worker count was part of the identity is reused, not trained again."""
    cfg = _cfg(tmp_path, stage1={"epochs": 3, "data": {"num_workers": 4}})
    old = decoder_dir_for(cfg, legacy=True)
    assert old != decoder_dir_for(cfg)
    old.mkdir(parents=True)
    _fake_train(old)
    assert ensure_decoder(cfg, lambda d: (_ for _ in ()).throw(AssertionError("retrained"))) == old


def test_an_unfinished_decoder_of_the_older_identity_is_resumed_in_place(tmp_path):
    cfg = _cfg(tmp_path, stage1={"epochs": 3, "data": {"num_workers": 4}})
    old = decoder_dir_for(cfg, legacy=True)
    (old / "checkpoints").mkdir(parents=True)  # a stage 1 interrupted before the identity changed
    trained = []
    assert ensure_decoder(cfg, lambda d: (trained.append(d), _fake_train(d))) == old and trained == [old]


def test_a_damaged_finished_decoder_is_rewritten_not_trusted(tmp_path, caplog):
    """A truncated decoder.pt in a DONE folder gave every stage-2 run a raw unpickling traceback."""
    cfg = _cfg(tmp_path)
    folder = ensure_decoder(cfg, _fake_train)
    decoder = folder / DECODER_FILE
    decoder.write_bytes(decoder.read_bytes()[:100])
    calls = []
    with caplog.at_level("WARNING"):
        assert ensure_decoder(cfg, lambda d: (calls.append(d), _fake_train(d))) == folder
    assert calls == [folder] and f"stage-1 decoder {decoder} is damaged" in caplog.text
    assert ensure_decoder(cfg, lambda d: calls.append(d)) == folder and len(calls) == 1  # intact again: reused


def test_naming_the_default_module_class_keeps_the_decoder_a_custom_one_does_not(tmp_path):
    """stage1.module._target_ came after decoders were trained: at its default it leaves the identity as it was."""
    before = decoder_dir_for(_cfg(tmp_path, stage1={"epochs": 3, "module": {"lr_net": 1e-3}}))
    named = {"epochs": 3, "module": {"_target_": "ushape.decoder.autodecoder.AutoDecoderModule", "lr_net": 1e-3}}
    assert decoder_dir_for(_cfg(tmp_path, stage1=named)) == before
    custom = {"epochs": 3, "module": {"_target_": "my_lab.MyAutoDecoder", "lr_net": 1e-3}}
    assert decoder_dir_for(_cfg(tmp_path, stage1=custom)) != before


def test_a_moved_data_class_keeps_the_decoders_trained_on_it(tmp_path):
    """ShapeNetWorld moved from ushape.data.real_world to ushape.data.real.shapenet_world."""
    data = {"root": str(tmp_path / "shapenet"), "category": "chairs"}
    old = _cfg(tmp_path, data={**data, "_target_": "ushape.data.real_world.ShapeNetWorld"})
    new = _cfg(tmp_path, data={**data, "_target_": "ushape.data.real.shapenet_world.ShapeNetWorld"})
    assert decoder_dir_for(new) == decoder_dir_for(old)


def test_bf16_auto_is_hashed_as_what_it_resolves_to(tmp_path, monkeypatch):
    """Without AMX "auto" trains in fp32: the same decoder as bf16 false (trained before "auto" existed)."""
    from ushape.decoder import precision

    def folder(bf16):
        stage1 = {"epochs": 3, "module": {"bf16": bf16}, "latent_optim": {"bf16": bf16}}
        return decoder_dir_for(_cfg(tmp_path, stage1=stage1, trainer={"accelerator": "cpu"}))

    for amx, same_as in ((False, False), (True, True)):
        monkeypatch.setattr(precision, "_auto_bf16", lambda device, amx=amx: amx)
        assert folder("auto") == folder(same_as) != folder(not same_as)
