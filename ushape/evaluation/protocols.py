"""The paper's evaluation protocols as per-item records: single view, multi view, corrupted views.

A record is one scored reconstruction: {encoder, label, protocol, min_scale, method, views,
shape_id, item, iou, cd, emd?}. `summarise` averages records into table cells.
- single view: every test view on its own (Table 1; the 1-view rows of Tables 3 and 5).
- multi view: each shape's renders grouped into instances of `group_size` (10) views, as Pix3D-MV
  groups Pix3D's images; each instance fused by every method (Table 3; the 10-view rows of Table 5).
- corrupted: the same with every input cropped to a random area in [min_scale, 1] (Tables 4-5).
A deterministic (l2) encoder is FroDO*: it fuses by averaging and has no Bayesian rows.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import partial
from typing import Callable, Iterable, Sequence

from tqdm.auto import tqdm

from ushape.decoder.artifacts import CodeTable
from ushape.evaluation.views import Encodings, Estimate, ViewKey
from ushape.fusion.rules import FusedCode, fuse_average, fuse_bayesian, fuse_bayesian_k

FuseFn = Callable[..., FusedCode]
# A reconstruction method's step after fusion (methods.ReconstructionMethod.after_fusion, bound to a run and crop).
AfterFusion = Callable[[Estimate, Sequence[ViewKey]], Estimate]
SINGLE_VIEW = "single-view"
GROUP_SIZE = 10


@dataclass(frozen=True)
class EncoderSpec:
    """One encoder under test: its loss name (es/nll/l2), its table label and whether it predicts variance."""

    name: str
    label: str
    probabilistic: bool


def encoder_label(loss: str) -> str:
    """The paper's name for an encoder trained with `loss`."""
    return {"es": "Ours", "nll": "Ours-NLL", "l2": "FroDO*"}.get(loss, loss)


def group_views(keys: Sequence[ViewKey], group_size: int = GROUP_SIZE, drop_short: bool = False) -> list[list[ViewKey]]:
    """Each shape's views in consecutive instances of group_size; a short tail is dropped.

    A shape with fewer than group_size views becomes one smaller instance (with a warning), so a
    small world still has a multi-view protocol; with drop_short it has none (Pix3D-MV's rule).
    """
    if group_size < 1:
        raise ValueError(f"group_size must be >= 1 view per instance, got {group_size}")
    by_shape: dict[str, list[ViewKey]] = {}
    for key in keys:
        by_shape.setdefault(key.shape_id, []).append(key)
    groups = []
    for shape_id, views in by_shape.items():
        if len(views) < group_size and drop_short:
            continue
        if len(views) < group_size:
            warnings.warn(
                f"shape {shape_id} has {len(views)} views, fewer than group_size={group_size}: "
                "fusing all of them as one instance",
                stacklevel=2,
            )
            groups.append(views)
            continue
        groups += [views[i : i + group_size] for i in range(0, len(views) - group_size + 1, group_size)]
    return groups


def method_name(rule: str, k: int | None = None) -> str:
    return {"average": "average", "bayesian": "bayesian"}.get(rule, f"bayesian-{k}")


def fusion_methods(probabilistic: bool, ks: Iterable[int] = ()) -> dict[str, FuseFn]:
    """Fusion rules by table name: average always; bayesian and bayesian-K only with predicted variance."""
    methods: dict[str, FuseFn] = {"average": fuse_average}
    if probabilistic:
        methods["bayesian"] = fuse_bayesian
        for k in ks:
            methods[method_name("bayesian_k", k)] = partial(fuse_bayesian_k, k=k)
    return methods


def single_view_records(
    spec: EncoderSpec, encodings: Encodings, reconstructor, min_scale: float, emd: bool = False
) -> list[dict]:
    """One record per view: its own code reconstructed and scored (with `fallback` where the encodings say)."""
    records = []
    for i, key in enumerate(tqdm(encodings.keys, desc=f"{spec.name} single view {min_scale:g}", leave=False)):
        scores = reconstructor.scores(encodings.mu[i], key.shape_id, emd=emd)
        record = _record(spec, "single", min_scale, SINGLE_VIEW, 1, key.shape_id, f"{key.view}", scores)
        if encodings.fallbacks is not None:
            record["fallback"] = encodings.fallbacks[i]
        records.append(record)
    return records


REFERENCES = {"ref_codes": "Stage-1 codes (decoder ceiling)", "ref_mean": "Mean training code (no image)"}


def reference_records(codes: CodeTable, train_codes: CodeTable, shape_ids: Sequence[str], reconstructor) -> list[dict]:
    """What an encoder's IoU means: each test shape reconstructed from its own stage-1 code (the best any
    encoder can do with this decoder) and from the mean training code (what ignoring the image gives)."""
    mean = train_codes.codes.mean(0)
    records = []
    for shape_id in tqdm(shape_ids, desc="reference codes", leave=False):
        for name, code in (("ref_codes", codes.lookup(shape_id)), ("ref_mean", mean)):
            spec = EncoderSpec(name, REFERENCES[name], probabilistic=False)
            scores = reconstructor.scores(code, shape_id, emd=True)
            records.append(_record(spec, "reference", 1.0, SINGLE_VIEW, 0, shape_id, "-", scores))
    return records


def multi_view_records(
    spec: EncoderSpec,
    encodings: Encodings,
    groups: Sequence[Sequence[ViewKey]],
    methods: dict[str, FuseFn],
    reconstructor,
    min_scale: float,
    quiet: bool = True,
    after: AfterFusion | None = None,
) -> list[dict]:
    """One record per (instance, fusion method): the fused code reconstructed and scored.

    quiet silences the fusion's "K > views" warning: the tables' Bayesian-K rows expect it for short instances.
    after: a reconstruction method's step from each fused Gaussian to the one scored (a refinement on the
    instance's views), applied once per instance and rule; its records carry `fallback`.
    """
    records = []
    for group in tqdm(groups, desc=f"{spec.name} multi view {min_scale:g}", leave=False):
        mu, var = encodings.select(group)
        shape_id = group[0].shape_id
        item = f"{group[0].view}-{group[-1].view}"
        with warnings.catch_warnings():
            if quiet:
                warnings.simplefilter("ignore")
            fused = {name: fuse(mu, var) for name, fuse in methods.items()}
        for name, code in fused.items():
            estimate = Estimate(code.mu, code.var)
            estimate = estimate if after is None else after(estimate, group)
            scores = reconstructor.scores(estimate.mu, shape_id)
            record = _record(spec, "multi", min_scale, name, len(group), shape_id, item, scores)
            if after is not None:
                record["fallback"] = estimate.fallback
            records.append(record)
    return records


def _record(
    spec: EncoderSpec, protocol: str, min_scale: float, method: str, views: int, shape_id: str, item: str, scores: dict
) -> dict:
    return {
        "encoder": spec.name,
        "label": spec.label,
        "protocol": protocol,
        "min_scale": float(min_scale),
        "method": method,
        "views": views,
        "shape_id": shape_id,
        "item": item,
        **{k: scores[k] for k in ("iou", "cd", "emd") if k in scores},
    }


CELL_KEYS = ("encoder", "label", "protocol", "min_scale", "method", "views")


def summarise(records: Iterable[dict]) -> list[dict]:
    """Mean iou / cd / emd per table cell (encoder, protocol, min_scale, method, views), with the count n.

    CD and EMD average over the non-empty reconstructions only; `empty` counts the others (IoU 0);
    `fallbacks`, in a cell of a method that may fall back (its records carry `fallback`), counts those that did.
    """
    cells: dict[tuple, list[dict]] = {}
    for record in records:
        cells.setdefault(tuple(record[k] for k in CELL_KEYS), []).append(record)
    rows = []
    for key, items in cells.items():
        row = dict(zip(CELL_KEYS, key))
        row["n"] = len(items)
        row["iou"] = sum(r["iou"] for r in items) / len(items)
        for metric in ("cd", "emd"):
            values = [r[metric] for r in items if metric in r and not math.isnan(r[metric])]
            if any(metric in r for r in items):
                row[metric] = sum(values) / len(values) if values else math.nan
        row["empty"] = sum(1 for r in items if math.isnan(r.get("cd", 0.0)))
        if any("fallback" in r for r in items):
            row["fallbacks"] = sum(1 for r in items if r.get("fallback"))
        rows.append(row)
    return rows
