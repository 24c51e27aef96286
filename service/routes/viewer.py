"""The web page (``/``, files of ``service/static/`` and of :mod:`moju_viewer.assets`) and the
data its result viewer draws.

The page is plain HTML, CSS and JavaScript, served as files, with no build step. Its 3D plots
are drawn by plotly.js, served from the ``plotly`` Python package installed with the service
(``/static/plotly.min.js``), so the page works without internet access.

The viewer reads a finished job through two endpoints: ``viewer-data`` (point labels,
colours, triangles, axis ranges, convergence history) and ``viewer-data/frames/{frame}``
(one frame's points), both built by :mod:`moju_viewer.data`, the module that also feeds
``moju view``.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Annotated
from uuid import UUID

from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi import Path as PathParameter
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from moju_viewer import data as viewer
from moju_viewer.assets import ASSET_NAMES, asset_path, plotly_js_path
from service.deps import Caller, JobId, Services, ServicesDep, get_caller
from service.errors import FrameOutOfRange
from service.routes.downloads import finished_record
from service.routes.jobs import UNAUTHORIZED
from service.schemas import ErrorBody

#: The service's own page files (the viewer's script and style come from moju_viewer).
STATIC_DIR = Path(__file__).resolve().parents[1] / "static"
#: The files of the page, by the name they are served under (``/static/<name>``).
PAGE_FILES = ("index.html", "app.js", *ASSET_NAMES)


def page_file(name: str) -> Path:
    """Where one of :data:`PAGE_FILES` is stored."""
    return asset_path(name) if name in ASSET_NAMES else STATIC_DIR / name


router = APIRouter()

_EXAMPLE = "http://127.0.0.1:8000/v1/jobs/0b7e9f6c-3a51-4f0e-9d7c-2c1e8a4b5d60"
_ERRORS = {
    404: {"model": ErrorBody, "description": "No such job (or no such frame)."},
    409: {"model": ErrorBody, "description": "The job has not finished, so there is no result."},
}

MaxPoints = Annotated[
    int,
    Query(
        ge=1,
        le=viewer.DEFAULT_MAX_POINTS,
        description=(
            "Most points per frame. A result with more points is shown through a fixed "
            "random subset of this size, the same in every frame; pass the same value to "
            "both viewer-data endpoints."
        ),
    ),
]


class AxisRanges(BaseModel):
    """[low, high] of each coordinate over every frame (shown points), padded by 5 %."""

    model_config = ConfigDict(extra="forbid")

    x: list[float] = Field(min_length=2, max_length=2, examples=[[-1.2, 1.0]])
    y: list[float] = Field(min_length=2, max_length=2, examples=[[-0.7, 0.9]])
    z: list[float] = Field(min_length=2, max_length=2, examples=[[-1.4, 1.5]])
    depth: list[float] = Field(
        min_length=2, max_length=2, description="Of the depth values of the frames."
    )


class ViewerSummary(BaseModel):
    """What the result viewer needs besides the frames' points."""

    model_config = ConfigDict(extra="forbid")

    job_id: UUID
    frames: int = Field(description="Number of frames F.", examples=[10])
    points: int = Field(description="Number of points P of the result.", examples=[28880])
    shown_points: int = Field(
        description="Points per frame in the viewer-data frames: min(P, max_points).",
        examples=[20000],
    )
    decimated: bool = Field(description="True when shown_points < points.")
    point_indices: list[int] | None = Field(
        None,
        description=(
            "When decimated: the index (0..P-1) of each shown point, increasing; the same "
            "subset in every frame. Null when every point is shown."
        ),
    )
    labels: list[int] = Field(description="Local group label of each shown point.")
    groups: int = Field(description="Number of distinct labels among the shown points.")
    colors: list[str] | None = Field(
        None, description="Uploaded colour of each shown point as #rrggbb; null if none."
    )
    faces: list[list[int]] | None = Field(
        None,
        description=(
            "Uploaded triangles (M x 3 point indices); null when none were uploaded or when "
            "the points are decimated."
        ),
    )
    ranges: AxisRanges
    rotations: list[list[list[float]]] = Field(
        description="Camera rotation of each frame, rows r1 and r2 (F x 2 x 3)."
    )
    history: dict[str, list[float | None]] = Field(
        description=(
            "Convergence history, one value per iteration: gap, rho, reprojection, ... "
            "(null where not finite)."
        )
    )
    n_iter: int = Field(description="ADMM iterations run.", examples=[120])
    stop_reason: str = Field(description="converged, rho_max or max_iter.")
    observed_fraction: float = Field(
        description=(
            "Fraction of the F x P (frame, point) entries that were observed; below 1 the "
            "frames list the points the solver filled in."
        ),
        examples=[1.0],
    )


class ViewerFrame(BaseModel):
    """One frame's shown points as columns (rounded to 1e-4 of the largest coordinate)."""

    model_config = ConfigDict(extra="forbid")

    frame: int = Field(description="Frame number, 0-based.", examples=[0])
    x: list[float]
    y: list[float]
    z: list[float]
    depth: list[float] = Field(
        description="Depth along the frame's optical axis r1 x r2 (camera rotation rows)."
    )
    unobserved: list[int] = Field(
        default_factory=list,
        description=(
            "Positions (0-based, in this frame's lists) of the points not observed in this "
            "frame: filled in by the solver. Empty when every shown point was observed."
        ),
    )


@router.get(
    "/v1/jobs/{job_id}/viewer-data",
    tags=["downloads"],
    operation_id="get_viewer_data",
    summary="What the result viewer draws, besides the points",
    description=(
        "For a finished job: point labels, uploaded colours and triangles, axis ranges over "
        "every frame, and the convergence history. Results with more than `max_points` "
        "points (at most 20,000) are decimated to a fixed random subset, listed in "
        "`point_indices`; the triangles are then left out. The points of each frame come "
        "from `viewer-data/frames/{frame}`. The web page at `/` uses both.\n\n"
        f"    curl '{_EXAMPLE}/viewer-data?max_points=20000'"
    ),
    response_model=ViewerSummary,
    responses={**_ERRORS, **UNAUTHORIZED},
    dependencies=[Depends(get_caller)],
)
def get_viewer_data(
    job_id: JobId,
    services: ServicesDep,
    caller: Caller,
    max_points: MaxPoints = viewer.DEFAULT_MAX_POINTS,
) -> ViewerSummary:
    """The viewer's summary of a finished job."""
    finished_record(services, job_id, caller)
    faces, colors = services.storage.mesh_attributes(job_id)
    with _open_result(services, job_id) as view:
        indices = viewer.shown_points(view.n_points, max_points)
        data = viewer.summary(view, indices, faces=faces, colors=colors)
    return ViewerSummary(job_id=job_id, **data)


@router.get(
    "/v1/jobs/{job_id}/viewer-data/frames/{frame}",
    tags=["downloads"],
    operation_id="get_viewer_frame",
    summary="One frame's points, for the result viewer",
    description=(
        "The shown points of frame `frame` (0-based) as columns x, y, z and depth (along the "
        "frame's optical axis), rounded to 1e-4 of the frame's largest coordinate; the same "
        "points, in the same order, as the labels of `viewer-data` with the same "
        "`max_points`.\n\n"
        f"    curl {_EXAMPLE}/viewer-data/frames/0"
    ),
    response_model=ViewerFrame,
    responses={**_ERRORS, **UNAUTHORIZED},
    dependencies=[Depends(get_caller)],
)
def get_viewer_frame(
    job_id: JobId,
    services: ServicesDep,
    caller: Caller,
    frame: Annotated[int, PathParameter(ge=0, description="Frame number, 0-based.", examples=[0])],
    max_points: MaxPoints = viewer.DEFAULT_MAX_POINTS,
) -> ViewerFrame:
    """One frame of a finished job, for the viewer."""
    finished_record(services, job_id, caller)
    with _open_result(services, job_id) as view:
        if frame >= view.n_frames:
            raise FrameOutOfRange(
                f"job {job_id} has {view.n_frames} frames (0..{view.n_frames - 1}); there is "
                f"no frame {frame}"
            )
        indices = viewer.shown_points(view.n_points, max_points)
        return ViewerFrame(**viewer.frame_data(view, frame, indices))


def _open_result(
    services: Services, job_id: UUID
) -> contextlib.AbstractContextManager[viewer.ResultView]:
    # The stored HDF5 file, read one frame at a time.
    return viewer.open_result(services.storage.result_file(job_id, "h5"))


# --------------------------------------------------------------------------------------------
# The page


@router.get("/", include_in_schema=False)
async def index() -> FileResponse:
    """The web page: submit, follow, download and view jobs."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")


@router.get("/static/{name}", include_in_schema=False)
async def static_file(name: str) -> FileResponse:
    """A file of the page, or plotly.js; only the names listed here are ever served."""
    if name == "plotly.min.js":
        path = plotly_js_path()
        if path is None:
            raise HTTPException(
                503, "the web page needs the plotly package: pip install 'moju[service]'"
            )
        return FileResponse(path, media_type="text/javascript")
    if name not in PAGE_FILES:
        raise HTTPException(
            404, f"no file /static/{name}; the page's files are {', '.join(PAGE_FILES)}"
        )
    return FileResponse(page_file(name))
