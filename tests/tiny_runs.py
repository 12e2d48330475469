"""The Hydra overrides that shrink `train.py experiment=quickstart` to a run of seconds, written once.

`tiny_train(changes, drop)` gives them with some values changed (or keys added) and some keys left out.
"""

TINY_TRAIN = {
    "experiment": "quickstart",
    "data.n_train": 3,
    "data.n_val": 1,
    "data.n_test": 1,
    "data.samples_per_shape": 4000,
    "data.n_views": 2,
    "data.image_size": 32,
    "data.mesh_resolution": 64,
    "data.num_workers": 0,
    "stage1.max_epochs": 2,
    "stage1.module.val_every_n_epochs": 2,
    "stage1.module.val_mesh_resolution": 16,
    "stage1.data.shapes_per_batch": 3,
    "stage1.data.samples_per_shape": 256,
    "stage1.data.val_num_shapes": 1,
    "stage1.latent_optim.iterations": 3,
    "stage1.latent_optim.samples_per_iter": 256,
    "stage2.max_epochs": 1,
    "stage2.data.image_size": 32,
    "stage2.data.batch_size": 4,
    "stage2.module.log_meshes": "false",
    "stage2.module.val_samples": 20,
    "encoder.backbone.pretrained": "false",
    "stage2.demo_meshes.resolution": 24,
    "trainer.enable_progress_bar": "false",
    "+trainer.enable_model_summary": "false",
}


def tiny_train(changes: dict | None = None, drop: tuple[str, ...] = ()) -> list[str]:
    """TINY_TRAIN as `key=value` overrides, with `changes` applied (new keys appended) and `drop` left out."""
    merged = {key: value for key, value in TINY_TRAIN.items() if key not in drop}
    merged.update(changes or {})
    return [f"{key}={value}" for key, value in merged.items()]
