"""Video jobs run in-process: a tracking stage, then the solve; failures and cancels while
tracking. The video is a tiny render of the rolling paper (96 x 72 pixels, 8 frames)."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from uuid import UUID, uuid4

import cv2
import numpy as np
import pytest

from moju_core.footage.render import render_sequence, write_video
from moju_core.footage.tracking import count_grid_points
from moju_core.params import SolverParams
from service.schemas import InputSummary, JobRecord, VideoSummary
from service.states import JobStatus
from service.storage import INPUT_NAME, TRACKS_NAME
from worker.jobs import execute

N_FRAMES, SIZE = 8, (96, 72)


@pytest.fixture(scope="module")
def rendered():
    return render_sequence("paper", width=SIZE[0], height=SIZE[1], n_frames=N_FRAMES)


def add_video_job(store, storage, rendered, directory: Path, frames=None, mask=True) -> UUID:
    """Store a queued video job as the API does (video, mask, first frame, record)."""
    frames = rendered.frames if frames is None else frames
    video = write_video(directory / "clip.mp4", frames)
    mask_path = None
    if mask:
        mask_path = directory / "mask.png"
        cv2.imwrite(str(mask_path), rendered.mask.astype(np.uint8) * 255)
    first = directory / "first.png"
    cv2.imwrite(str(first), rendered.frames[0])
    job_id = uuid4()
    storage.create(job_id)
    storage.write_video(job_id, video, mask_path, first)
    record = JobRecord(
        id=job_id,
        status=JobStatus.QUEUED,
        created_at=datetime.now(timezone.utc),
        parameters=SolverParams(max_iter=3, seed=1),
        input=InputSummary(
            frames=N_FRAMES,
            points=count_grid_points(rendered.mask),
            format="video",
            size_bytes=0,
            has_rotations=False,
            has_ground_truth=False,
            has_faces=False,
            has_colors=True,
            video=VideoSummary(width=SIZE[0], height=SIZE[1], has_mask=mask, step=4),
        ),
    )
    with store.connection.pipeline() as pipe:
        store.add(record, pipe)
        pipe.execute()
    return job_id


def spy_on_progress(store) -> list[dict]:
    reports = []
    report = store.report_progress

    def spy(job_id, progress, attempt=None):
        reports.append(dict(progress))
        return report(job_id, progress, attempt)

    store.report_progress = spy
    return reports


def test_video_job_reports_tracking_then_solving(store, storage, settings, rendered, tmp_path):
    job_id = add_video_job(store, storage, rendered, tmp_path)
    reports = spy_on_progress(store)
    assert execute(job_id, store, storage, settings)["status"] == "finished"
    stages = [report["stage"] for report in reports]
    tracking = [report for report in reports if report["stage"] == "tracking"]
    assert stages[: len(tracking)] == ["tracking"] * len(tracking)  # tracking comes first
    assert tracking[0]["iteration"] == 1 and tracking[0]["max_iter"] == N_FRAMES
    assert 0 < tracking[0]["fraction"] <= 1 and tracking[0]["gap"] is None
    assert "iterating" in stages[len(tracking) :]
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.FINISHED and record.progress.stage == "finished"
    summary = record.result.tracking
    assert summary.tracks == count_grid_points(rendered.mask)
    assert 0 < summary.reconstructed <= summary.tracks and 0 < summary.fraction_kept <= 1
    with np.load(storage.tracks_file(job_id), allow_pickle=False) as data:
        assert data["W"].shape == (2 * N_FRAMES, summary.reconstructed)
    assert storage.read_result(job_id).shapes.shape == (N_FRAMES, summary.reconstructed, 3)
    assert storage.read_input(job_id).colors.shape == (summary.reconstructed, 3)


def test_tracking_without_a_mask_warns_in_the_result(
    store, storage, settings, rendered, tmp_path
) -> None:
    job_id = add_video_job(store, storage, rendered, tmp_path, mask=False)
    assert execute(job_id, store, storage, settings)["status"] == "finished"
    warnings = store.get(job_id, reconcile_with_rq=False).result.warnings
    assert any(w.startswith("no mask given: tracking the textured region") for w in warnings)


def test_a_video_the_tracker_cannot_use_fails_the_job(
    store, storage, settings, rendered, tmp_path
) -> None:
    # Independent noise in every frame: no flow is consistent, the tracker loses every track.
    noise = np.random.default_rng(0).integers(0, 256, rendered.frames.shape, dtype=np.uint8)
    job_id = add_video_job(store, storage, rendered, tmp_path, frames=noise)
    assert execute(job_id, store, storage, settings) == {"status": "failed"}
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.FAILED
    assert record.error.startswith("fewer than 3 tracks are left from frame ")
    assert "too few for a camera" in record.error
    assert not storage.has_result(job_id)


def test_cancel_during_tracking_stops_the_job(store, storage, settings, rendered, tmp_path):
    job_id = add_video_job(store, storage, rendered, tmp_path)
    report, status = store.report_progress, store.status
    looks = []

    def cancel_on_first_report(job, progress, attempt=None):
        answer = report(job, progress, attempt)
        if progress["stage"] == "tracking":
            store.cancel(job)
        return answer

    def counted_status(job):
        looks.append(job)
        return status(job)

    store.report_progress, store.status = cancel_on_first_report, counted_status
    assert execute(job_id, store, storage, settings) == {"status": "cancelled"}
    # Between throttled reports every frame looks at the status: the next frame saw it.
    assert 1 <= len(looks) < N_FRAMES - 1
    assert status(job_id) is JobStatus.CANCELLED
    directory = settings.data_dir / "jobs" / str(job_id)
    assert not (directory / TRACKS_NAME).exists() and not (directory / INPUT_NAME).exists()
    assert not storage.has_result(job_id)


def test_a_retry_discards_the_tracks_but_keeps_the_upload(
    store, storage, settings, rendered, tmp_path
) -> None:
    job_id = add_video_job(store, storage, rendered, tmp_path)
    assert execute(job_id, store, storage, settings)["status"] == "finished"
    removed = storage.discard_outputs(job_id)
    assert {"tracks.npz", "input.npz", "result.h5"} <= set(removed)
    directory = settings.data_dir / "jobs" / str(job_id)
    assert sorted(p.name for p in directory.iterdir()) == [
        "first_frame.png", "mask.png", "video.mp4",
    ]  # fmt: skip
    video, mask = storage.video_files(job_id)
    assert video.name == "video.mp4" and mask is not None
