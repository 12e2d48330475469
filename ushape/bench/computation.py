"""Wall-clock cost of each step of reconstruction with uncertainty, per decoder architecture.

Decoders: a trained one when `decoder_dir` is given (with one of its test codes), else the config's
architecture (seed 0, code ~ N(0, 0.01 I)) fitted to a procedural chair for `fit_steps` steps
(`ushape.bench.fitted`), or with `fit_steps=0` left random with the last layer's bias shifted by the
median SDF of a 32^3 grid so that the zero level set cuts the cube and there is a mesh to time.
Timings depend on the architecture and the grid size, not on the weights, except coarse-to-fine
extraction, the narrow band and vertex counts, which depend on how much surface there is: a random
field has surface everywhere, so those rows mean something only for a fitted or trained decoder.

Slow rows of big decoders can be measured on a random subset of the grid's points and scaled
linearly to the full grid; such rows are marked "extrapolated" with the fraction they ran on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch import nn

from ushape.bench.contract import precision_rows
from ushape.bench.depth import depth_rows, orbit_cameras
from ushape.bench.fitted import fitted_decoder
from ushape.bench.refine import pose_rows, refine_rows
from ushape.bench.timing import Measurement, timed
from ushape.decoder.artifacts import codes_file, load_codes, load_decoder
from ushape.decoder.folded import fold_code
from ushape.decoder.query import code_sdf_fn, frozen
from ushape.fusion.rules import fuse_average, fuse_bayesian, fuse_bayesian_k
from ushape.mesh.extraction import extract_mesh, marching_cubes
from ushape.propagation.field import decode_field, narrow_band_field
from ushape.propagation.mesh import grid_points, propagate, vertex_uncertainty
from ushape.refinement.joint import PoseSettings
from ushape.workspace import CONFIG_DIR


@dataclass(frozen=True)
class BenchSettings:
    resolution: int = 128
    n_samples: int = 10
    repeats: int = 1  # for the decoder-heavy rows
    fusion_repeats: int = 2000
    fusion_views: int = 10
    field_fraction: float = 1.0  # of grid points timed for the uncertainty fields (1: all)
    skip_slow: bool = False  # skip the MC field entirely
    seed: int = 0
    depth_views: int = 12  # views of the depth-uncertainty rows (0: skip them)
    depth_size: int = 48  # their pixels per side
    depth_var: float = 0.001  # per-dimension latent variance of their Gaussian
    refine_views: int = 12  # views of the refinement rows (0: skip them)
    refine_size: int = 64  # their pixels per side
    pose_azimuths: int = 8  # starting azimuths of the pose-estimated refinement rows (0: skip them)
    precision: str = "fp32"  # what `precision: auto` resolved to on this machine (bench.py resolves it)
    precision_why: str = ""
    precision_rows: bool = True  # time the mesh with uncertainty in fp32, bf16 and auto, with the contract
    precision_only: bool = False  # only those rows (no other decoder rows, encoders or fusion)


def bench_decoder(
    config_name: str, decoder_dir: str | Path | None = None, fit_steps: int = 0, cache_dir: str | Path | None = None
) -> tuple[nn.Module, torch.Tensor, str]:
    """(decoder, code [D], where they came from) for conf/decoder/<config_name>.yaml or a trained folder."""
    if decoder_dir is not None:
        decoder = load_decoder(decoder_dir)
        table = load_codes(Path(decoder_dir) / codes_file("test"))
        return decoder, table.codes[0], f"trained ({decoder_dir})"
    path = CONFIG_DIR / "decoder" / f"{config_name}.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"no decoder config {path}; choose one of conf/decoder/*.yaml")
    config = OmegaConf.load(path)
    torch.manual_seed(0)
    decoder = instantiate(config).eval().requires_grad_(False)
    code = 0.1 * torch.randn(int(config.latent_size))
    if fit_steps > 0:
        decoder, provenance = fitted_decoder(config, code, fit_steps, None if cache_dir is None else Path(cache_dir))
        return decoder, code, provenance
    _centre_surface(decoder, code)
    return decoder, code, "random weights"


def _centre_surface(decoder: nn.Module, code: torch.Tensor) -> None:
    """Shift the output bias so the median SDF over a 32^3 grid is 0 (a random net has a surface then)."""
    with frozen(decoder):
        field_values = decode_field(decoder, code, 32)
    last = [m for m in decoder.modules() if isinstance(m, nn.Linear)][-1]
    with torch.no_grad():
        # tanh output: shift the pre-activation by atanh of the median
        median = float(field_values.median().clamp(-0.99, 0.99))
        last.bias -= torch.atanh(torch.tensor(median)) if getattr(decoder, "output_tanh", False) else median


def fusion_rows(settings: BenchSettings, latent_size: int) -> list[Measurement]:
    """Median milliseconds-scale timings of the three fusion rules on V views."""
    g = torch.Generator().manual_seed(settings.seed)
    mu = torch.randn(settings.fusion_views, latent_size, generator=g)
    var = torch.rand(settings.fusion_views, latent_size, generator=g) + 0.01
    rows = []
    for name, fn in (
        ("fusion bayesian", lambda: fuse_bayesian(mu, var)),
        ("fusion average", lambda: fuse_average(mu, var)),
        ("fusion bayesian-4", lambda: fuse_bayesian_k(mu, var, 4)),
    ):
        seconds, _ = timed(fn, settings.fusion_repeats, warmup=20)
        rows.append(
            Measurement(name, seconds, settings.fusion_repeats, note=f"{settings.fusion_views} views, D={latent_size}")
        )
    return rows


def encoder_row(encoder_config: str, image_size: int, latent_size: int, repeats: int = 5) -> Measurement:
    """One image through a random-weight encoder of conf/encoder/<encoder_config>.yaml."""
    config = OmegaConf.load(CONFIG_DIR / "encoder" / f"{encoder_config}.yaml")
    config.latent_size = latent_size
    config.backbone.pretrained = False
    encoder = instantiate(config, _recursive_=False).eval()
    image = torch.rand(1, 3, image_size, image_size)
    with torch.no_grad():
        seconds, _ = timed(lambda: encoder(image), repeats, warmup=1)
    return Measurement(f"encoder {encoder_config}", seconds, repeats, note=f"{image_size}px, 1 image, random weights")


def _field_uncertainty_row(decoder, code, var, settings: BenchSettings, method: str) -> Measurement:
    """MC or linearised SDF mean+variance on the N^3 grid, or on a fraction of it scaled up."""
    points = grid_points(settings.resolution)
    fraction = settings.field_fraction
    if fraction < 1.0:
        keep = torch.randperm(points.shape[0], generator=torch.Generator().manual_seed(settings.seed))
        points = points[keep[: max(1, int(fraction * points.shape[0]))]]
    g = torch.Generator().manual_seed(settings.seed)
    seconds, _ = timed(lambda: propagate(decoder, code, var, points, method, settings.n_samples, g), settings.repeats)
    label = f"field uncertainty {method}" + (f" M={settings.n_samples}" if method == "mc" else "")
    note = arithmetic_floor_note(decoder, code) if method == "linearised" else ""
    if fraction < 1.0:
        return Measurement(
            label,
            seconds / fraction,
            settings.repeats,
            extrapolated_from=fraction,
            note=note,
            points=settings.resolution**3,
        )
    return Measurement(label, seconds, settings.repeats, note=note, points=settings.resolution**3)


def arithmetic_floor_note(decoder: nn.Module, code: torch.Tensor) -> str:
    """The linearised field's cost over the plain field's if both ran at the same multiply-adds per second."""
    with frozen(decoder):
        folded = fold_code(decoder, code)
    if folded is None:
        return ""
    forward, backward = folded.multiply_adds()
    return f"arithmetic floor {1 + backward / forward:.2f}x ({forward:,} + {backward:,} multiply-adds per point)"


def decoder_rows(decoder: nn.Module, code: torch.Tensor, settings: BenchSettings) -> list[Measurement]:
    """Field (fp32, bf16), marching cubes, meshes and uncertainty rows for one decoder."""
    n, reps = settings.resolution, settings.repeats
    var = torch.full_like(code, 0.01)
    if settings.precision_only:
        return _precision_rows(decoder, code, var, settings)
    rows: list[Measurement] = []
    with frozen(decoder):
        for bf16 in (False, True):  # first calls pay for allocator and kernel set-up; keep that out
            decode_field(decoder, code, 16, bf16=bf16)
        field_s, grid = timed(lambda: decode_field(decoder, code, n), reps)
        rows.append(Measurement("decoder field fp32", field_s, reps))
        bf16_s, _ = timed(lambda: decode_field(decoder, code, n, bf16=True), reps)
        rows.append(Measurement("decoder field bf16", bf16_s, reps))
        mc_s, mesh = timed(lambda: marching_cubes(grid), max(reps, 3))
        rows.append(Measurement("marching cubes", mc_s, max(reps, 3), note=f"{len(mesh.vertices)} vertices"))
        rows.append(Measurement("mesh dense (field + MC)", field_s + mc_s, reps, note="sum of the two rows above"))
        c2f_s, (mesh, stats) = timed(
            lambda: extract_mesh(code_sdf_fn(decoder, code), n, "coarse_to_fine", coarse_resolution=min(32, n)), reps
        )
        rows.append(
            Measurement(
                "mesh coarse-to-fine",
                c2f_s,
                reps,
                note=f"{stats.evaluations} of {stats.dense_evaluations} points, {len(mesh.vertices)} vertices",
            )
        )
    vertices = torch.as_tensor(mesh.vertices, dtype=torch.float32)
    g = torch.Generator().manual_seed(settings.seed)
    for method in ("mc", "linearised"):
        s, _ = timed(lambda: vertex_uncertainty(decoder, code, var, vertices, method, settings.n_samples, g), reps)
        label = f"vertex uncertainty {method}" + (f" M={settings.n_samples}" if method == "mc" else "")
        rows.append(Measurement(label, s, reps, note=f"{len(vertices)} vertices", points=len(vertices)))
    for method in ("mc", "linearised"):
        if method == "mc" and settings.skip_slow:
            continue
        rows.append(_field_uncertainty_row(decoder, code, var, settings, method))
    rows += narrow_band_rows(decoder, code, var, settings)
    # A fused multi-view posterior's spread, not the codes' prior one (0.01): first-order depth is
    # meant for a Gaussian whose samples land on the same parts of the object.
    depth_var = torch.full_like(code, settings.depth_var)
    if settings.precision_rows:
        rows += _precision_rows(decoder, code, var, settings)
    if settings.depth_views > 0:
        rows += depth_rows(
            decoder,
            code,
            depth_var,
            settings.depth_views,
            settings.depth_size,
            settings.n_samples,
            seed=settings.seed,
            repeats=reps,
        )
    if settings.refine_views > 0:
        rows += refine_rows(decoder, code, settings.refine_views, settings.refine_size, seed=settings.seed)
        if settings.pose_azimuths > 0:
            rows += pose_rows(
                decoder,
                code,
                settings.refine_views,
                settings.refine_size,
                seed=settings.seed,
                pose_settings=PoseSettings(azimuths=settings.pose_azimuths),
            )
    return rows


def _precision_rows(decoder: nn.Module, code: torch.Tensor, var: torch.Tensor, settings: BenchSettings):
    """The mesh with uncertainty in fp32, bf16 and auto, with the contract (depth std over the depth rows' views)."""
    cameras = orbit_cameras(settings.depth_views, settings.depth_size) if settings.depth_views > 0 else ()
    depth_var = torch.full_like(code, settings.depth_var)
    return precision_rows(
        decoder,
        code,
        var,
        settings.resolution,
        settings.precision,
        settings.repeats,
        cameras,
        settings.depth_size,
        depth_var,
    )


def narrow_band_rows(
    decoder: nn.Module, code: torch.Tensor, var: torch.Tensor, settings: BenchSettings
) -> list[Measurement]:
    """SDF mean and variance on the N^3 grid with the variance only in the narrow band, both methods."""
    rows = []
    for method in ("linearised", "mc"):
        g = torch.Generator().manual_seed(settings.seed)
        seconds, band = timed(
            lambda: narrow_band_field(decoder, code, var, settings.resolution, method, settings.n_samples, g),
            settings.repeats,
        )
        label = f"field uncertainty {method}" + (f" M={settings.n_samples}" if method == "mc" else "")
        rows.append(
            Measurement(
                f"{label} narrow band",
                seconds,
                settings.repeats,
                note=f"mean at {band.evaluations}, variance at {band.band_points} of {settings.resolution**3} points",
            )
        )
    return rows


@dataclass
class DecoderBench:
    name: str
    provenance: str
    parameters: int
    rows: list[Measurement] = field(default_factory=list)

    def seconds(self, prefix: str) -> float | None:
        """Seconds of the first row whose name starts with prefix (None if not measured)."""
        return next((r.seconds for r in self.rows if r.name.startswith(prefix)), None)


def run_bench(
    settings: BenchSettings,
    decoders: dict[str, str | Path | None],
    field_fractions: dict[str, float] | None = None,
    encoders: tuple[tuple[str, int], ...] = (("efficientnet_lite0", 96), ("resnet50", 224)),
    fit_steps: int = 0,
    cache_dir: str | Path | None = None,
) -> tuple[list[Measurement], list[DecoderBench]]:
    """(shared rows: encoders and fusion, per-decoder benches) for {config name: trained folder or None}.

    Decoders without a folder are fitted to a procedural chair for fit_steps steps (cached in cache_dir).
    """
    benches, latent = [], 64
    for name, folder in decoders.items():
        decoder, code, provenance = bench_decoder(name, folder, fit_steps, cache_dir)
        fraction = (field_fractions or {}).get(name, settings.field_fraction)
        own = BenchSettings(**{**settings.__dict__, "field_fraction": fraction})
        bench = DecoderBench(name, provenance, sum(p.numel() for p in decoder.parameters()))
        bench.rows = decoder_rows(decoder, code, own)
        benches.append(bench)
        latent = int(code.shape[0])
    if settings.precision_only:
        return [], benches
    shared = [encoder_row(name, size, latent) for name, size in encoders]
    shared += fusion_rows(settings, latent)
    return shared, benches
