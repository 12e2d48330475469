"""The demo's page: its held-out shape from one view and from all, fused and refined, in one report.html."""

from analytic_decoder import run_with_ellipsoid

from ushape.data.layout import WorldIndex, read_split
from ushape.training.demo_meshes import write_demo_meshes

LATENT = 8


def test_the_demo_writes_one_page_with_every_view_count_and_mode(tiny_run, tmp_path):
    run = run_with_ellipsoid(tiny_run, tmp_path, LATENT)
    root = tiny_run["world"]
    world = WorldIndex(root, "chairs", {s: read_split(root, s) for s in ("train", "val", "test")})
    out = write_demo_meshes(run, world, tmp_path / "meshes", resolution=24, split="test", refine="masks")
    page = (out / "report.html").read_text()
    labels = [
        "1 view, fused",
        "1 view, refined",
        "1 view, refined, pose estimated",
        "3 views, fused",
        "3 views, refined",
    ]
    positions = [page.index(f'"label": "{label}"') for label in labels]
    assert positions == sorted(positions)  # one view first, fused before refined
    assert (out / "model-viewer-umd.min.js").is_file() and (out / "demo_colourbar.png").is_file()
    assert '"rotation std (deg)"' in page and '"rotation error (deg)"' in page
    shape = read_split(root, "test")[0]
    views = len(list((root / "renders" / shape).glob("*.png")))
    assert views > 0 and page.count('<img class="view"') == views  # the input views as thumbnails
