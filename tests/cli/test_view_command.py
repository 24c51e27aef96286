"""``moju view``: the result viewer as one standalone HTML file.

The file is checked here by its contents; tests/service/test_service_browser.py opens it in
a real browser.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from plotly.offline import get_plotlyjs

from moju_cli.main import cli
from moju_cli.view_commands import STANDALONE_POINT_BUDGET, default_max_points
from moju_core import reconstruct
from moju_core.datasets import make_sequence
from moju_core.io import Measurements, write_measurements, write_result
from moju_core.params import SolverParams
from moju_viewer.assets import read_asset


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A 300-point face: its input (with triangles and colours) and its result (h5)."""
    directory = tmp_path_factory.mktemp("view")
    sequence = make_sequence("face1", n_points=300)
    measurements = Measurements(W=sequence.W, faces=sequence.faces, colors=sequence.colors)
    result = reconstruct(sequence.W, SolverParams(max_iter=30))
    return {
        "input": write_measurements(directory / "tracks.npz", measurements),
        "result": write_result(directory / "result.h5", result),
        "other": write_measurements(
            directory / "other.npz", Measurements(W=make_sequence("face1", n_points=200).W)
        ),
    }


def embedded_document(page: str) -> dict:
    match = re.search(
        r'<script type="application/json" id="moju-viewer-data">(.*?)</script>', page, re.S
    )
    assert match, "no embedded data"
    return json.loads(match.group(1))


def test_writes_a_self_contained_page(files, tmp_path: Path) -> None:
    output = tmp_path / "viewer.html"
    run = CliRunner().invoke(
        cli, ["view", str(files["result"]), "--input", str(files["input"]), "-o", str(output)]
    )
    assert run.exit_code == 0, run.output
    assert f"wrote {output} (10 frames, all 300 points, " in run.output
    page = output.read_text()

    # Everything inline: plotly.js from the plotly package, the viewer's script and style.
    assert get_plotlyjs() in page
    assert read_asset("viewer.js") in page
    assert read_asset("style.css") in page
    assert not re.search(r"""<(?:script|link|img)[^>]+(?:src|href)=["'](?!data:)""", page)
    assert page.count("</script>") == page.count("<script")

    document = embedded_document(page)
    summary = document["summary"]
    assert (summary["frames"], summary["points"], summary["shown_points"]) == (10, 300, 300)
    assert summary["faces"] is not None and len(summary["colors"]) == 300
    assert [frame["frame"] for frame in document["frames"]] == list(range(10))
    assert all(len(frame["x"]) == 300 for frame in document["frames"])
    assert "<title>MoJu result: result.h5</title>" in page


def test_default_output_name_and_decimation(files) -> None:
    run = CliRunner().invoke(cli, ["view", str(files["result"]), "--max-points", "50"])
    assert run.exit_code == 0, run.output
    output = files["result"].with_suffix(".html")
    assert f"wrote {output} (10 frames, 50 of 300 points per frame, " in run.output
    summary = embedded_document(output.read_text())["summary"]
    assert summary["decimated"] and len(summary["point_indices"]) == 50
    assert summary["faces"] is None and summary["colors"] is None


def test_default_points_per_frame_keep_the_file_bounded() -> None:
    assert default_max_points(10) == 20_000
    assert default_max_points(1_000) == STANDALONE_POINT_BUDGET // 1_000
    assert default_max_points(100_000) == 100


def test_refuses_a_mismatched_input_and_a_file_that_is_no_result(files) -> None:
    mismatched = CliRunner().invoke(
        cli, ["view", str(files["result"]), "--input", str(files["other"])]
    )
    assert mismatched.exit_code == 1
    assert (
        f"Error: {files['other']} has 200 points but the result has 300: give the input file "
        "the result was reconstructed from"
    ) in mismatched.output

    not_a_result = CliRunner().invoke(cli, ["view", str(files["input"])])
    assert not_a_result.exit_code == 1
    assert "tracks.npz is not a readable MoJu result file" in not_a_result.output


def test_says_what_to_install_without_plotly(files, tmp_path: Path, monkeypatch) -> None:
    # As if plotly were not installed: no plotly.min.js to be found.
    monkeypatch.setattr("moju_cli.view_commands.plotly_js_path", lambda: None)
    run = CliRunner().invoke(cli, ["view", str(files["result"]), "-o", str(tmp_path / "v.html")])
    assert run.exit_code == 1
    assert "moju view needs the plotly package: pip install 'moju[service]'" in run.output
    assert not (tmp_path / "v.html").exists()


def test_embedded_data_cannot_close_its_script_element() -> None:
    """A "</script>" in the data stays inside the JSON; the title is escaped."""
    from moju_cli.view_commands import standalone_html

    document = {"summary": {"note": "</script><script>alert(1)</script>"}, "frames": []}
    page = standalone_html(document, title="<b>t</b>", subtitle="s")
    assert embedded_document(page) == document
    assert "<title>&lt;b&gt;t&lt;/b&gt;</title>" in page


def test_filled_in_points_are_marked_in_the_page(files, tmp_path: Path) -> None:
    import dataclasses

    from moju_core.io import read_result

    visibility = np.ones((10, 300), dtype=bool)
    visibility[2, 5:9] = False
    occluded = dataclasses.replace(read_result(files["result"]), visibility=visibility)
    result_path = write_result(tmp_path / "occluded.h5", occluded)
    output = tmp_path / "occluded.html"
    run = CliRunner().invoke(cli, ["view", str(result_path), "-o", str(output)])
    assert run.exit_code == 0, run.output
    page = output.read_text()
    document = embedded_document(page)
    assert document["frames"][2]["unobserved"] == [5, 6, 7, 8]
    assert document["frames"][3]["unobserved"] == []
    assert document["summary"]["observed_fraction"] == pytest.approx(1 - 4 / 3000)
    assert "10 frames x 300 points, 99.9 % observed," in page
