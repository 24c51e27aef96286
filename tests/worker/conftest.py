"""Fixtures of the worker tests: a job store and storage on the test Redis, jobs to run."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from datetime import datetime, timezone
from pathlib import Path
from uuid import UUID, uuid4

import numpy as np
import pytest
from redis import Redis

from moju_core.datasets import make_sequence
from moju_core.io import Measurements
from moju_core.params import SolverParams
from service.job_store import JobStore
from service.schemas import InputSummary, JobRecord
from service.settings import Settings
from service.states import JobStatus
from service.storage import LocalStorage


@pytest.fixture
def settings(redis_url: str, tmp_path: Path) -> Settings:
    return Settings(redis_url=redis_url, data_dir=tmp_path / "data", cleanup_interval=0)


@pytest.fixture
def store(redis_url: str, settings: Settings) -> Iterator[JobStore]:
    connection = Redis.from_url(redis_url)
    yield JobStore(connection, retention_seconds=settings.result_ttl)
    connection.close()


@pytest.fixture
def storage(settings: Settings) -> LocalStorage:
    return LocalStorage(settings.data_dir)


@pytest.fixture
def add_job(store: JobStore, storage: LocalStorage) -> Callable[..., UUID]:
    """Store a queued job (input and record) as the API would; return its id."""

    def add(W: np.ndarray, params: SolverParams | None = None, rotations=None) -> UUID:
        measurements = Measurements(W=W, rotations=rotations)
        job_id = uuid4()
        storage.create(job_id)
        storage.write_input(job_id, measurements)
        record = JobRecord(
            id=job_id,
            status=JobStatus.QUEUED,
            created_at=datetime.now(timezone.utc),
            parameters=params or SolverParams(),
            input=InputSummary(
                frames=measurements.n_frames,
                points=measurements.n_points,
                format="npz",
                size_bytes=0,
                has_rotations=rotations is not None,
                has_ground_truth=False,
                has_faces=False,
                has_colors=False,
            ),
        )
        with store.connection.pipeline() as pipe:
            store.add(record, pipe)
            pipe.execute()
        return job_id

    return add


@pytest.fixture(scope="session")
def face_W() -> np.ndarray:
    """Tracks of a 300-point, 10-frame face."""
    return make_sequence("face1", n_points=300).W


@pytest.fixture(scope="session")
def long_W() -> np.ndarray:
    """Tracks of a 2,000-point, 10-frame face: with the tests' ``LONG`` parameters a solve
    that runs for tens of seconds (the 300-point face runs its 10,000 iterations in 5 s)."""
    return make_sequence("face1", n_points=2_000).W
