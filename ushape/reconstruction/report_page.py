"""report.html: a reconstruction to turn around in a browser, offline, beside its other files.

The 3D view is Google's <model-viewer> (Apache-2.0; its UMD build, pinned at 4.4.0 from the npm
registry, vendored in ushape/reconstruction/viewer/, 1.07 MB; three.js inside): a maintained web
component that loads glTF with vertex colours (COLOR_0) and orbits it with mouse or touch. Chosen over
a Python server (viser) because the page must open from a zipped folder with no process running, and
over three.js alone because its ES modules cannot be imported from file:// pages; the UMD build is a
classic script, which can. Each scene is embedded in the page once, as a base64 GLB (a file:// page
cannot fetch a file beside it), coloured by its std; the toggle's plain grey twin is made in the page
by overwriting its COLOR_0. Cameras are drawn as frustums (line segments) in the same GLB. The folder
holds report.html, model-viewer-umd.min.js and the files reconstruct.py writes anyway; nothing is
fetched from the network.

The mesh is drawn unlit (KHR_materials_unlit) with its shading baked into the page: a fixed light from
above, left and front, half-Lambert shading, stored per vertex in COLOR_0's alpha, which the page
turns into the colours' brightness (std colours mildly, plain grey strongly) and then sets opaque.
Measured with notebooks/report_load_time.py on a GPU-less 2-core machine (software WebGL), model-viewer's
physically based material took 3x as long to draw the first mesh as the unlit one, and its default
environment half of what was left (the demo's lit page 5.7-6.6 s; a 12-view page unlit 2.1-2.35 s, and
with the flat environment below 1.1-1.4 s; docs/commands.md). The baked light does not
follow the camera; the shape still reads as it turns. The std colours are darkened by at most 35 % where
the baked light does not reach, so read values off the colour bar where a part faces the light.
"""

from __future__ import annotations

import base64
import html
import io
import json
import shutil
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import trimesh
from PIL import Image

from ushape import atomic
from ushape.workspace import REPORT_FILE

VIEWER_DIR = Path(__file__).resolve().parent / "viewer"
VIEWER_JS = "model-viewer-umd.min.js"

FRUSTUM_COLOUR = (5, 48, 183, 255)  # linear: (40, 120, 220) in sRGB
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


LIGHT = np.array([-0.5, 1.0, 0.45]) / np.linalg.norm([-0.5, 1.0, 0.45])  # the baked light: above, left, front (y up)


def baked_shade(normals: np.ndarray) -> np.ndarray:
    """Half-Lambert (0.5 n . l + 0.5)^2 [N] in [0, 1] of outward unit vertex normals [N, 3] under the fixed
    LIGHT: 1 facing it, 1/4 side-on, 0 only facing straight away, so the side away from the light still shows
    its shape as the object turns (plain Lambert leaves half of every mesh one flat dark)."""
    return np.clip(0.5 * (np.asarray(normals, np.float64) @ LIGHT) + 0.5, 0.0, 1.0) ** 2


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB values in [0, 1] (a colour map's) as the linear values glTF's COLOR_0 holds: drawn unlit, the
    viewer encodes them back to the same sRGB on screen (stored as sRGB they came out washed pale)."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def scene_glb(scene: Scene) -> bytes:
    """The scene as one compact GLB: the mesh (positions, its std colours as COLOR_0 with the baked shade in
    their alpha, 16-bit indices where they fit; unlit) and every camera's frustum as coloured lines. The page
    makes the plain-shaded copy itself (greying COLOR_0), so each scene is stored once."""
    mesh = scene.coloured
    colours = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)[:, :4].copy()
    colours[:, :3] = np.round(srgb_to_linear(colours[:, :3] / 255.0) * 255).astype(np.uint8)
    colours[:, 3] = np.round(baked_shade(mesh.vertex_normals) * 255).astype(np.uint8)
    primitives = [(np.asarray(mesh.vertices, np.float32), colours, np.asarray(mesh.faces).reshape(-1), TRIANGLES)]
    if len(scene.cameras):
        segments = np.concatenate([frustum_segments(K, w2c, hw, FRUSTUM_DEPTH) for K, w2c, hw in scene.cameras])
        points = segments.reshape(-1, 3).astype(np.float32)
        line_colours = np.tile(np.asarray(FRUSTUM_COLOUR, np.uint8), (len(points), 1))
        primitives.append((points, line_colours, np.arange(len(points)), LINES))
    return pack_glb(primitives)


TRIANGLES, LINES = 4, 1  # glTF primitive modes


def pack_glb(primitives: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, int]]) -> bytes:
    """A binary glTF 2.0 of one mesh whose primitives are (positions [N, 3] float32, colours [N, 4] uint8,
    indices [M], mode), all with one unlit material (KHR_materials_unlit: the colours are drawn as they are);
    COLOR_0 is normalised uint8, indices uint16 where every index fits, else uint32."""
    blob, views, accessors, prims = bytearray(), [], [], []

    def add(array: np.ndarray, component: int, kind: str, target: int, normalized: bool = False, bounds=False) -> int:
        while len(blob) % 4:
            blob.append(0)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": array.nbytes, "target": target})
        blob.extend(array.tobytes())
        accessor = {"bufferView": len(views) - 1, "componentType": component, "count": len(array), "type": kind}
        if normalized:
            accessor["normalized"] = True
        if bounds:
            accessor["min"], accessor["max"] = array.min(axis=0).tolist(), array.max(axis=0).tolist()
        accessors.append(accessor)
        return len(accessors) - 1

    for positions, colours, indices, mode in primitives:
        small = len(positions) < 65536
        index = add(np.asarray(indices, np.uint16 if small else np.uint32), 5123 if small else 5125, "SCALAR", 34963)
        position = add(np.ascontiguousarray(positions, np.float32), 5126, "VEC3", 34962, bounds=True)
        colour = add(np.ascontiguousarray(colours, np.uint8), 5121, "VEC4", 34962, normalized=True)
        attributes = {"POSITION": position, "COLOR_0": colour}
        prims.append({"attributes": attributes, "indices": index, "mode": mode, "material": 0})
    while len(blob) % 4:
        blob.append(0)
    gltf = {
        "asset": {"version": "2.0", "generator": "ushape"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": prims}],
        "materials": [{"pbrMetallicRoughness": {"metallicFactor": 0.0}, "extensions": {"KHR_materials_unlit": {}}}],
        "extensionsUsed": ["KHR_materials_unlit"],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def flat_environment() -> str:
    """A 4 x 2 white PNG (data URI) as the viewer's environment map. The scene is unlit, so the environment
    lights nothing; model-viewer's default ("neutral", a room it renders and pre-filters) took most of the
    time to the first mesh in software WebGL, and a tiny map is pre-filtered at once."""
    buffer = io.BytesIO()
    Image.new("RGB", (4, 2), (255, 255, 255)).save(buffer, format="PNG")
    return data_uri(buffer.getvalue(), "image/png")


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
    appendix: str = "",  # more HTML under the figures (an evaluation's tables and plots)
) -> Path:
    """report.html (and the viewer script) in out_dir; returns the page's path."""
    out_dir = Path(out_dir)
    shutil.copy2(VIEWER_DIR / VIEWER_JS, out_dir / VIEWER_JS)
    entries = [
        {"label": s.label, "glb": base64.b64encode(scene_glb(s)).decode("ascii"), "figures": s.figures} for s in scenes
    ]
    bar = ""
    if colour_bar is not None:
        source = data_uri(Path(colour_bar).read_bytes(), "image/png")
        bar = f'<img id="colourbar" alt="{html.escape(std_label)} colour bar" src="{source}">'
    thumbs = "".join(f'<img class="view" alt="view {i}" src="{thumbnail(v)}">' for i, v in enumerate(views))
    page = TEMPLATE.format(
        title=html.escape(title),
        viewer_js=VIEWER_JS,
        environment=flat_environment(),
        scenes=json.dumps(entries),
        figures=json.dumps(figures or {}),
        slider="true" if slider else "false",
        colour_bar=bar,
        thumbnails=thumbs,
        appendix=appendix,
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
<model-viewer id="viewer" camera-controls shadow-intensity="0" exposure="1.0" tone-mapping="none"
  environment-image="{environment}" interaction-prompt="none" alt="the reconstruction"></model-viewer>
<div>{colour_bar}</div>
<div id="views">{thumbnails}</div>
<table id="figures"></table>
{appendix}
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
// Each scene is one GLB (base64) whose mesh colours carry the baked shade in their alpha: the coloured view
// darkens the std colours a little by it, the plain twin (the same bytes) is grey shaded by it; both opaque.
function glbUrl(i, grey) {{
  const key = grey ? "plainUrl" : "url";
  if (SCENES[i][key]) return SCENES[i][key];
  const bytes = Uint8Array.from(atob(SCENES[i].glb), (c) => c.charCodeAt(0));
  const view = new DataView(bytes.buffer), jsonLength = view.getUint32(12, true);
  const gltf = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
  const binStart = 20 + jsonLength + 8;
  const colours = gltf.bufferViews[gltf.accessors[gltf.meshes[0].primitives[0].attributes.COLOR_0].bufferView];
  const rgba = bytes.subarray(binStart + colours.byteOffset, binStart + colours.byteOffset + colours.byteLength);
  for (let k = 0; k < rgba.length; k += 4) {{
    const shade = rgba[k + 3] / 255;
    if (grey) {{ rgba[k] = rgba[k + 1] = rgba[k + 2] = Math.round(150 * (0.12 + 0.88 * shade)); }}  // linear
    else {{ for (let c = 0; c < 3; c++) rgba[k + c] = Math.round(rgba[k + c] * (0.65 + 0.35 * shade)); }}
    rgba[k + 3] = 255;
  }}
  SCENES[i][key] = URL.createObjectURL(new Blob([bytes], {{ type: "model/gltf-binary" }}));
  return SCENES[i][key];
}}
function show() {{
  if (!SCENES.length) {{  // nothing to turn around (an evaluation without showcase meshes)
    viewer.style.display = document.getElementById("controls").style.display = "none";
    document.getElementById("figures").innerHTML = "";
    return;
  }}
  viewer.src = glbUrl(scene, plain);
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
viewer.addEventListener("load", () => {{  // when the mesh is drawn: ms since navigation (the load-time check)
  document.body.dataset.loadedMs = Math.round(performance.now());
}});
show();
if (location.hash.indexOf("toggle") >= 0) toggle.click();  // what a user's click does (the browser test's hook)
</script>
</body></html>
"""
