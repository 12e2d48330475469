"""report.html: a reconstruction to turn around in a browser, offline, beside its other files.

The 3D view is Google's <model-viewer> (Apache-2.0; its UMD build, pinned at 4.4.0 from the npm
registry, vendored in ushape/reconstruction/viewer/, 1.07 MB; three.js inside): a maintained web
component that loads glTF with vertex colours (COLOR_0) and orbits it with mouse or touch. Chosen over
a Python server (viser) because the page must open from a zipped folder with no process running, and
over three.js alone because its ES modules cannot be imported from file:// pages; the UMD build is a
classic script, which can. Each scene is embedded in the page as a base64 GLB (a file:// page cannot
fetch a file beside it), twice: coloured by its std, and plain grey (the toggle). Cameras are drawn as
frustums (line segments) in the same GLB. The folder holds report.html, model-viewer-umd.min.js and
the files reconstruct.py writes anyway; nothing is fetched from the network.
"""

from __future__ import annotations

import base64
import html
import io
import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import trimesh
from PIL import Image

from ushape import atomic

VIEWER_DIR = Path(__file__).resolve().parent / "viewer"
VIEWER_JS = "model-viewer-umd.min.js"
REPORT_FILE = "report.html"
PLAIN_GREY = (200, 200, 200, 255)
FRUSTUM_COLOUR = (40, 120, 220, 255)
FRUSTUM_DEPTH = 0.35  # how far (world units) a camera's frustum reaches towards the object
THUMBNAIL = 96  # px, the input views' thumbnails


@dataclass
class Scene:
    """One mesh the page can show: its label, the mesh coloured by its std, and the cameras to draw."""

    label: str
    coloured: trimesh.Trimesh  # vertex colours set (export.coloured_mesh)
    cameras: Sequence[tuple[np.ndarray, np.ndarray, tuple[int, int]]] = ()  # (K [3,3], world_to_cam [4,4], (H, W))
    figures: dict[str, Any] = field(default_factory=dict)


def frustum_segments(K: np.ndarray, world_to_cam: np.ndarray, hw: tuple[int, int], depth: float) -> np.ndarray:
    """Line segments [8, 2, 3] of a camera's frustum in world coordinates: centre to the image's four corners
    at `depth` along the optical axis, and the rectangle joining them."""
    (h, w), K_inv = hw, np.linalg.inv(np.asarray(K, np.float64))
    corners = np.array([[0.0, 0.0, 1.0], [w, 0.0, 1.0], [w, h, 1.0], [0.0, h, 1.0]]) @ K_inv.T * depth
    cam_to_world = np.linalg.inv(np.asarray(world_to_cam, np.float64))
    world = corners @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]
    centre = cam_to_world[:3, 3]
    spokes = [(centre, c) for c in world]
    rim = [(world[i], world[(i + 1) % 4]) for i in range(4)]
    return np.array(spokes + rim)


def scene_glb(scene: Scene, plain: bool) -> bytes:
    """The scene as one GLB: the mesh (its std colours, or plain grey) and every camera's frustum."""
    mesh = scene.coloured.copy()
    if plain:
        mesh.visual.vertex_colors = np.tile(PLAIN_GREY, (len(mesh.vertices), 1))
    parts = trimesh.Scene(mesh)
    if len(scene.cameras):
        segments = np.concatenate([frustum_segments(K, w2c, hw, FRUSTUM_DEPTH) for K, w2c, hw in scene.cameras])
        path = trimesh.load_path(segments)
        path.colors = np.tile(FRUSTUM_COLOUR, (len(path.entities), 1))
        parts.add_geometry(path)
    return parts.export(file_type="glb")


def data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def thumbnail(image: np.ndarray) -> str:
    """A view [H, W, 3] in [0, 1] as a small PNG data URI."""
    picture = Image.fromarray((np.clip(image, 0, 1) * 255).astype(np.uint8))
    picture.thumbnail((THUMBNAIL, THUMBNAIL))
    buffer = io.BytesIO()
    picture.save(buffer, format="PNG")
    return data_uri(buffer.getvalue(), "image/png")


def write_report(
    out_dir: str | Path,
    title: str,
    scenes: Sequence[Scene],
    views: Sequence[np.ndarray] = (),  # the input views [H, W, 3] in [0, 1]
    colour_bar: str | Path | None = None,  # the std colour bar PNG (beside the page)
    std_label: str = "SDF std",
    figures: dict[str, Any] | None = None,  # summary figures shown under the view
    slider: bool = False,  # a slider over the scenes (a next-best-view sequence) instead of a chooser
) -> Path:
    """report.html (and the viewer script) in out_dir; returns the page's path."""
    out_dir = Path(out_dir)
    shutil.copy2(VIEWER_DIR / VIEWER_JS, out_dir / VIEWER_JS)
    entries = [
        {
            "label": s.label,
            "coloured": data_uri(scene_glb(s, plain=False), "model/gltf-binary"),
            "plain": data_uri(scene_glb(s, plain=True), "model/gltf-binary"),
            "figures": s.figures,
        }
        for s in scenes
    ]
    bar = ""
    if colour_bar is not None:
        source = data_uri(Path(colour_bar).read_bytes(), "image/png")
        bar = f'<img id="colourbar" alt="{html.escape(std_label)} colour bar" src="{source}">'
    thumbs = "".join(f'<img class="view" alt="view {i}" src="{thumbnail(v)}">' for i, v in enumerate(views))
    page = TEMPLATE.format(
        title=html.escape(title),
        viewer_js=VIEWER_JS,
        scenes=json.dumps(entries),
        figures=json.dumps(figures or {}),
        slider="true" if slider else "false",
        colour_bar=bar,
        thumbnails=thumbs,
    )
    path = out_dir / REPORT_FILE
    atomic.write_text(path, page)
    return path


TEMPLATE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<script src="{viewer_js}"></script>
<style>
body {{ font-family: sans-serif; margin: 1em; background: #fafafa; }}
model-viewer {{ width: 720px; height: 540px; background: #ffffff; border: 1px solid #ccc; }}
#controls {{ margin: 0.5em 0; }} .view {{ margin: 2px; border: 1px solid #ccc; }}
table {{ border-collapse: collapse; }} td, th {{ border: 1px solid #ddd; padding: 2px 8px; text-align: left; }}
</style></head>
<body>
<h2>{title}</h2>
<div id="controls">
  <label id="chooser-label">Show <select id="chooser"></select></label>
  <label id="slider-label">View <input id="slider" type="range" min="0" value="0"> <span id="step"></span></label>
  <button id="toggle">plain shading</button>
</div>
<model-viewer id="viewer" camera-controls shadow-intensity="0" exposure="1.0"
  environment-image="neutral" interaction-prompt="none" alt="the reconstruction"></model-viewer>
<div>{colour_bar}</div>
<div id="views">{thumbnails}</div>
<table id="figures"></table>
<script>
const SCENES = {scenes};
const FIGURES = {figures};
const SLIDER = {slider};
let scene = 0, plain = location.hash.indexOf("plain") >= 0;
const viewer = document.getElementById("viewer"), chooser = document.getElementById("chooser");
const slider = document.getElementById("slider"), toggle = document.getElementById("toggle");
document.getElementById(SLIDER ? "chooser-label" : "slider-label").style.display = "none";
slider.max = SCENES.length - 1;
SCENES.forEach((s, i) => {{
  const o = document.createElement("option"); o.value = i; o.text = s.label; chooser.add(o);
}});
function table() {{
  const rows = Object.assign({{}}, FIGURES, SCENES[scene].figures);
  const shown = (v) => (typeof v === "number" && !Number.isInteger(v) ? v.toPrecision(4) : v);
  document.getElementById("figures").innerHTML = Object.entries(rows).map(
    ([k, v]) => "<tr><th>" + k + "</th><td>" + shown(v) + "</td></tr>").join("");
}}
function show() {{
  viewer.src = plain ? SCENES[scene].plain : SCENES[scene].coloured;
  toggle.textContent = plain ? "colour by std" : "plain shading";
  document.getElementById("step").textContent = SCENES[scene].label;
  document.body.dataset.shown = SCENES[scene].label + (plain ? " plain" : " coloured");
  table();
}}
chooser.onchange = () => {{ scene = +chooser.value; show(); }};
slider.oninput = () => {{ scene = +slider.value; show(); }};
toggle.onclick = () => {{ plain = !plain; show(); }};
const start = location.hash.match(/scene=(\\d+)/);
if (start) {{ scene = Math.min(+start[1], SCENES.length - 1); chooser.value = scene; slider.value = scene; }}
viewer.addEventListener("load", () => {{ document.body.dataset.loaded = "yes"; }});
show();
if (location.hash.indexOf("toggle") >= 0) toggle.click();  // what a user's click does (the browser test's hook)
</script>
</body></html>
"""
