"""``moju view``: the service's result viewer as one standalone HTML file.

The file holds everything it needs (plotly.js from the installed ``plotly`` package, the
viewer's script and style from :mod:`moju_viewer.assets`, and the result's frames as JSON), so
it opens in a browser without a server and without internet access. The data come from
:mod:`moju_viewer.data`, as for the service's viewer-data endpoints, so the file shows what
the web page shows.
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import click

from moju_core import __version__
from moju_core.errors import MeasurementError
from moju_core.io import atomic_output, read_measurements
from moju_viewer.assets import plotly_js_path, read_asset
from moju_viewer.data import DEFAULT_MAX_POINTS, ResultView, open_result, viewer_document

#: Points drawn over all frames together unless --max-points says otherwise: about 40 MB of
#: HTML, which a browser opens in a few seconds. Long sequences get fewer points per frame.
STANDALONE_POINT_BUDGET = 1_000_000

_PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<link rel="icon" href="data:,">
<style>
{style}
</style>
<script>
{plotly}
</script>
<script>
{viewer}
</script>
</head>
<body class="standalone">
<header class="page-header">
<h1>{title}</h1>
<p class="subtitle">{subtitle}</p>
</header>
<main>
<div id="viewer-container"></div>
</main>
<script type="application/json" id="moju-viewer-data">{data}</script>
<script>
(function () {{
  "use strict";
  const data = JSON.parse(document.getElementById("moju-viewer-data").textContent);
  const container = document.getElementById("viewer-container");
  new MojuViewer.Viewer(container, MojuViewer.embeddedSource(data)).load();
}})();
</script>
</body>
</html>
"""


def default_max_points(n_frames: int) -> int:
    """Points per frame of a standalone file: at most DEFAULT_MAX_POINTS, and about
    STANDALONE_POINT_BUDGET over all frames (never fewer than 100)."""
    return max(100, min(DEFAULT_MAX_POINTS, STANDALONE_POINT_BUDGET // max(n_frames, 1)))


def _script_text(text: str) -> str:
    """``text`` safe inside a <script> element: nothing in it may close the element."""
    # In JavaScript source, "<\\/" means "</" inside string and regular-expression literals,
    # the only places where "</script" can occur in a script.
    return text.replace("</script", "<\\/script").replace("</SCRIPT", "<\\/SCRIPT")


def _json_text(data: Any) -> str:
    """JSON for a <script type="application/json"> element (no "<" that HTML could read)."""
    return json.dumps(data, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")


def _viewer_assets() -> tuple[str, str, str]:
    """plotly.js, the viewer's script and its style sheet."""
    plotly = plotly_js_path()
    if plotly is None:
        raise click.ClickException(
            "moju view needs the plotly package: pip install 'moju[service]'"
        )
    return plotly.read_text(encoding="utf-8"), read_asset("viewer.js"), read_asset("style.css")


def standalone_html(document: dict[str, Any], *, title: str, subtitle: str) -> str:
    """The viewer as one HTML page showing ``document`` (from
    :func:`moju_viewer.data.viewer_document`)."""
    plotly_js, viewer_js, style = _viewer_assets()
    return _PAGE.format(
        title=html.escape(title),
        subtitle=html.escape(subtitle),
        style=style,
        plotly=_script_text(plotly_js),
        viewer=_script_text(viewer_js),
        data=_json_text(document),
    )


def _mesh_attributes(input_file: Path | None, view: ResultView) -> tuple[Any, Any]:
    if input_file is None:
        return None, None
    try:
        measurements = read_measurements(input_file)
    except (MeasurementError, ValueError, OSError) as exc:
        raise click.ClickException(f"cannot read {input_file}: {exc}") from exc
    n_points = measurements.W.shape[1]
    if n_points != view.n_points:
        raise click.ClickException(
            f"{input_file} has {n_points} points but the result has {view.n_points}: give the "
            "input file the result was reconstructed from"
        )
    return measurements.faces, measurements.colors


@click.command("view")
@click.argument("result_file", metavar="RESULT", type=click.Path(exists=True, dir_okay=False))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="HTML file to write [default: RESULT with the extension .html].",
)
@click.option(
    "--input",
    "input_file",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="The measurement file of the reconstruction: its triangles (drawn as a surface) and "
    "colours are shown too.",
)
@click.option(
    "--max-points",
    type=click.IntRange(1, DEFAULT_MAX_POINTS),
    default=None,
    help=f"Most points per frame; larger results show a fixed random subset [default: "
    f"{DEFAULT_MAX_POINTS:,}, fewer for long sequences so that the file stays near "
    f"{STANDALONE_POINT_BUDGET:,} points in all].",
)
def view(
    result_file: str, output: Path | None, input_file: Path | None, max_points: int | None
) -> None:
    """Write the result viewer for RESULT (npz or h5) as a standalone HTML file.

    The page shows the shapes as an interactive 3D point cloud (a surface with --input when
    the input has triangles), a frame slider and play button, colours by local group or by
    depth, and the convergence curve. Points the solver filled in (not observed in a frame)
    are drawn dimmed, or hidden on request. It needs no server and no internet access.
    """
    result_path = Path(result_file)
    output = output or result_path.with_suffix(".html")
    try:
        with open_result(result_path) as result:
            faces, colors = _mesh_attributes(input_file, result)
            per_frame = max_points or default_max_points(result.n_frames)
            document = viewer_document(result, max_points=per_frame, faces=faces, colors=colors)
    except ValueError as exc:
        raise click.ClickException(str(exc)) from exc
    summary = document["summary"]
    observed = summary["observed_fraction"]
    missing = f", {100 * observed:.1f} % observed" if observed < 1 else ""
    subtitle = (
        f"{result_path.name}: {summary['frames']} frames x {summary['points']} points"
        f"{missing}, {summary['n_iter']} iterations ({summary['stop_reason']}). Written by moju "
        f"{__version__}."
    )
    page = standalone_html(document, title=f"MoJu result: {result_path.name}", subtitle=subtitle)
    try:
        with atomic_output(output) as temporary:
            temporary.write_text(page, encoding="utf-8")
    except OSError as exc:
        raise click.ClickException(f"could not write {output}: {exc.strerror}") from exc
    shown = f"{summary['shown_points']:,} of {summary['points']:,} points per frame"
    if not summary["decimated"]:
        shown = f"all {summary['points']:,} points"
    click.echo(
        f"wrote {output} ({summary['frames']} frames, {shown}, "
        f"{len(page.encode()) / 2**20:.1f} MiB)"
    )


COMMANDS = [view]
