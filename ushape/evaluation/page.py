"""report.html of an evaluation: its showcase reconstructions in the 3D viewer (each coloured by its std,
chosen from a list), then every table and plot the evaluation wrote."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import trimesh

from ushape.evaluation.report import PLOTS_DIR
from ushape.evaluation.showcase import SHOWCASE_DIR
from ushape.evaluation.tables import TABLES_FILE
from ushape.reconstruction.export import DEFAULT_CMAP, colour_range, coloured_mesh, write_colour_bar
from ushape.reconstruction.report_page import Scene, data_uri, write_report


def markdown_tables(text: str) -> str:
    """The Markdown of tables.md as HTML: headings and pipe tables; other lines as paragraphs."""
    out, rows = [], []

    def flush() -> None:
        if rows:
            cells = [[html.escape(c.strip()) for c in row.strip().strip("|").split("|")] for row in rows]
            head, body = cells[0], [r for r in cells[1:] if not all(set(c) <= set("-: ") for c in r)]
            out.append(
                "<table><tr>"
                + "".join(f"<th>{c}</th>" for c in head)
                + "</tr>"
                + "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in body)
                + "</table>"
            )
            rows.clear()

    for line in text.splitlines():
        if line.lstrip().startswith("|"):
            rows.append(line)
            continue
        flush()
        if line.startswith("#"):
            level = min(len(line) - len(line.lstrip("#")) + 2, 6)
            out.append(f"<h{level}>{html.escape(line.lstrip('#').strip())}</h{level}>")
        elif line.strip():
            out.append(f"<p>{html.escape(line)}</p>")
    flush()
    return "\n".join(out)


def evaluation_page(out_dir: str | Path, title: str = "evaluation") -> Path:
    """out_dir/report.html from what an evaluation wrote there (showcase meshes, tables.md, plots/)."""
    out_dir = Path(out_dir)
    meshes = sorted((out_dir / SHOWCASE_DIR).glob("*.npz")) if (out_dir / SHOWCASE_DIR).is_dir() else []
    loaded = []
    for path in meshes:
        with np.load(path) as blob:
            loaded.append((path.stem, trimesh.Trimesh(blob["vertices"], blob["faces"], process=False), blob["std"]))
    top = colour_range(np.concatenate([std for _, _, std in loaded])) if loaded else 1.0
    scenes = [Scene(stem, coloured_mesh(mesh, std, top, DEFAULT_CMAP)) for stem, mesh, std in loaded]
    bar = None
    if scenes:
        bar = out_dir / "report_colourbar.png"
        write_colour_bar(bar, top)
    appendix = []
    if (out_dir / TABLES_FILE).is_file():
        appendix.append(markdown_tables((out_dir / TABLES_FILE).read_text()))
    for plot in sorted((out_dir / PLOTS_DIR).glob("*.png")) if (out_dir / PLOTS_DIR).is_dir() else []:
        appendix.append(
            f'<h3>{html.escape(plot.stem)}</h3><img alt="{html.escape(plot.stem)}" '
            f'src="{data_uri(plot.read_bytes(), "image/png")}" style="max-width: 720px">'
        )
    return write_report(out_dir, title, scenes, (), bar, appendix="\n".join(appendix))
