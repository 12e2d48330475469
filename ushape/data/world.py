"""The synthetic world: one category's procedural shapes with meshes, SDF samples and renders, cached.

The cache folder is named by a hash of the generating config, so changing any setting (or
GENERATOR_VERSION, bumped whenever generated content changes) builds a fresh world beside
the old one instead of silently mixing the two. Layout: see `ushape.data.layout`.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import logging
import os
import time
import warnings
from collections import Counter
from pathlib import Path
from typing import Any, Iterable, Optional

import numpy as np
from filelock import FileLock

from ushape import atomic
from ushape.data import integrity
from ushape.data.jobs import run_jobs
from ushape.data.layout import SPLITS, WorldIndex, world_dir_name
from ushape.data.shape_artifacts import ShapeFactory, ShapeJob, ShapeResult, artifact_problems, build_shape
from ushape.errors import InputError
from ushape.workspace import CONFIG_FILE

log = logging.getLogger(__name__)

GENERATOR_VERSION = 4  # 4: tables with attached shelves and twin-post trestle beams
SPLIT_STREAMS = {"train": 0, "val": 1, "test": 2}


def shape_seeds(world_seed: int, counts: dict[str, int]) -> dict[str, list[int]]:
    """Per split, one distinct 32-bit shape seed per index, derived from (world seed, split, index)."""
    used: set[int] = set()
    seeds: dict[str, list[int]] = {}
    for split in SPLITS:
        seeds[split] = []
        for i in range(counts[split]):
            candidates = np.random.SeedSequence(world_seed, spawn_key=(SPLIT_STREAMS[split], i)).generate_state(8)
            # A 32-bit collision is rare but possible; the next candidate keeps splits disjoint.
            seed = next(int(c) for c in candidates if int(c) not in used)
            used.add(seed)
            seeds[split].append(seed)
    return seeds


class SyntheticWorld:
    """Builds (once) and caches the synthetic dataset of one category under `root`."""

    def __init__(
        self,
        category: str,
        root: str,
        n_train: int,
        n_val: int,
        n_test: int,
        seed: int = 0,
        samples_per_shape: int = 100_000,
        n_views: int = 24,
        image_size: int = 137,
        mesh_resolution: int = 256,
        num_workers: int = 0,
        shape_factory: Optional[ShapeFactory] = None,
    ) -> None:
        counts = {"train": n_train, "val": n_val, "test": n_test}
        if any(int(n) < 0 for n in counts.values()) or n_train < 1:
            raise InputError(f"need n_train >= 1 and n_val, n_test >= 0, got {counts}")
        for name, value in (
            ("samples_per_shape", samples_per_shape),
            ("n_views", n_views),
            ("image_size", image_size),
            ("mesh_resolution", mesh_resolution),
        ):
            if int(value) < 1:
                raise InputError(f"{name} must be positive, got {value}")
        self.factory = shape_factory or default_shape_factory(category)
        self.root = Path(root).expanduser()
        self.counts = {k: int(v) for k, v in counts.items()}
        self.num_workers = int(num_workers)
        self.config: dict[str, Any] = {
            "category": category,
            "n_train": self.counts["train"],
            "n_val": self.counts["val"],
            "n_test": self.counts["test"],
            "seed": int(seed),
            "samples_per_shape": int(samples_per_shape),
            "n_views": int(n_views),
            "image_size": int(image_size),
            "mesh_resolution": int(mesh_resolution),
            "generator_version": GENERATOR_VERSION,
        }
        if shape_factory is not None:
            self.config["shape_factory"] = f"{shape_factory.__module__}.{shape_factory.__qualname__}"
        self.last_build: Counter = Counter()

    @property
    def config_hash(self) -> str:
        """First 12 hex digits of the SHA-256 of the canonical JSON config."""
        return hashlib.sha256(json.dumps(self.config, sort_keys=True).encode()).hexdigest()[:12]

    @property
    def directory(self) -> Path:
        return self.root / world_dir_name(self.config["category"], self.config_hash)

    def build(self) -> WorldIndex:
        """Generate whatever is missing or corrupt (idempotent) and return the world's index.

        After the call, `last_build` counts the artifacts made ("shape", "mesh", "sdf",
        "renders", and "splits"/"config" files); an up-to-date world makes none.
        """
        # One builder per world at a time: a second job waits, then finds everything made.
        self.directory.parent.mkdir(parents=True, exist_ok=True)
        with FileLock(str(self.directory) + ".lock"):
            return self._build()

    def _build(self) -> WorldIndex:
        start = time.perf_counter()
        self.last_build = Counter()
        if self.directory.is_dir():
            leftovers = atomic.remove_temp_files(self.directory)  # of builds killed mid-write
            if leftovers:
                log.info("removed %d temporary files of an interrupted build from %s", len(leftovers), self.directory)
        self._write_config()
        index = WorldIndex(root=self.directory, category=self.config["category"], splits={}, config=self.config)
        seeds = shape_seeds(self.config["seed"], self.counts)
        splits = {split: self._split_ids(index, split, seeds[split]) for split in SPLITS}
        all_ids = [sid for ids in splits.values() for sid in ids]
        if len(set(all_ids)) != len(all_ids):
            raise RuntimeError(f"splits of {self.directory} share shape ids; delete its splits/ folder to regenerate")
        index = WorldIndex(root=self.directory, category=index.category, splits=splits, config=self.config)
        jobs = [
            ShapeJob(index, split, i, seeds[split][i], sid, self.factory)
            for split in SPLITS
            for i, sid in enumerate(splits[split])
        ]
        for result in self._run(jobs):
            for path, reason in result.corrupt:
                warnings.warn(f"corrupt cache file {path} ({reason}); regenerating it", stacklevel=2)
            self.last_build.update(result.made)
        log.info(
            "%s world %s ready in %.1fs (made %s)",
            index.category,
            self.directory,
            time.perf_counter() - start,
            dict(self.last_build) or "nothing",
        )
        return WorldIndex.load(self.directory)

    @classmethod
    def from_index(cls, index: WorldIndex) -> Optional["SyntheticWorld"]:
        """The SyntheticWorld that built `index`, able to check and repair it; None if it cannot be rebuilt
        here (not a synthetic world, another generator version, an unimportable shape factory, a renamed folder)."""
        config = dict(index.config)
        if config.get("generator_version") != GENERATOR_VERSION:
            return None
        factory = None
        if "shape_factory" in config:
            module, _, name = str(config["shape_factory"]).rpartition(".")
            try:
                factory = getattr(importlib.import_module(module), name)
            except (ImportError, AttributeError, ValueError):
                return None
        try:
            world = cls(
                config["category"],
                str(index.root.parent),
                config["n_train"],
                config["n_val"],
                config["n_test"],
                config["seed"],
                config["samples_per_shape"],
                config["n_views"],
                config["image_size"],
                config["mesh_resolution"],
                shape_factory=factory,
            )
        except (KeyError, TypeError, ValueError):
            return None
        return world if world.config == config and world.directory.resolve() == index.root.resolve() else None

    def _write_config(self) -> None:
        path = self.directory / CONFIG_FILE
        problem = integrity.check_json(path)
        if problem is None and json.loads(path.read_text()) == self.config:
            return
        if problem not in (None, integrity.MISSING):
            warnings.warn(f"corrupt cache file {path} ({problem}); regenerating it", stacklevel=3)
        atomic.write_json(path, self.config)
        self.last_build["config"] += 1

    def _split_ids(self, index: WorldIndex, split: str, seeds: list[int]) -> list[str]:
        """Shape ids of a split, read from its file when valid, else generated and written."""
        path = index.split_path(split)
        problem = integrity.check_json(path)
        if problem is None:
            ids = json.loads(path.read_text())
            if isinstance(ids, list) and len(ids) == len(seeds) and all(isinstance(i, str) for i in ids):
                return ids
            problem = f"lists {len(ids) if isinstance(ids, list) else 'no'} ids, expected {len(seeds)}"
        if problem != integrity.MISSING:
            warnings.warn(f"corrupt cache file {path} ({problem}); regenerating it", stacklevel=3)
        ids = [self.factory(self.config["category"], s).shape_id for s in seeds]
        if len(set(ids)) != len(ids):
            raise RuntimeError(f"shape factory gave duplicate ids in split {split!r}: ids must be unique per seed")
        atomic.write_json(path, ids)
        self.last_build["splits"] += 1
        return ids

    def _run(self, jobs: list[ShapeJob]) -> Iterable[ShapeResult]:
        return run_jobs(build_shape, jobs, self.num_workers, desc=f"{self.config['category']} world", unit="shape")


def open_world(root: str | Path) -> WorldIndex:
    """A world folder for any command to read: laid out right, and for a synthetic world every file
    checked and the missing or corrupt ones regenerated (with a warning naming them), as `build` does."""
    index = WorldIndex.load(root)
    world = SyntheticWorld.from_index(index)
    if world is None:
        log.info("%s is not a synthetic world this version can rebuild: its files are not checked here", index.root)
        return index
    if not os.access(index.root.parent, os.W_OK):  # shared read-only data: check, but repair nothing
        problems = [
            f"{path} ({reason})" for sid in index.shape_ids() for path, reason in artifact_problems(index, sid).values()
        ]
        if problems:
            raise InputError(
                f"the read-only world {index.root} has {len(problems)} missing or corrupt files, e.g. "
                f"{'; '.join(problems[:3])}: copy the folder, keeping its name {index.root.name}, into a writable "
                f"folder (cp -r {index.root} DEST/) and evaluate the copy, world=DEST/{index.root.name} (it is "
                "repaired there; a renamed copy cannot be rebuilt)"
            )
        return index
    return world.build()


def default_shape_factory(category: str) -> ShapeFactory:
    """ushape.shapes.generate_shape, after checking the category is one it makes."""
    from ushape.shapes import CATEGORIES, generate_shape

    if category not in CATEGORIES:
        raise InputError(f"unknown category {category!r}; valid categories: {', '.join(CATEGORIES)}")
    return generate_shape
