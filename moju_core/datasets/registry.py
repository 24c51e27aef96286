"""The named benchmark sequences and :func:`make_sequence`."""

from __future__ import annotations

from moju_core.datasets.body import BODY_SEQUENCE_NAMES, body_sequence
from moju_core.datasets.faces import face_sequence
from moju_core.datasets.hard import HARD_GENERATORS, HARD_SEQUENCE_NAMES
from moju_core.datasets.noise import add_noise
from moju_core.datasets.sequence import Sequence
from moju_core.datasets.sheets import cloth_sequence, paper_sequence

SEQUENCE_NAMES: tuple[str, ...] = ("face1", "face2", "face3", "face4", "paper", "cloth")


_FACE_BENCHMARKS: dict[str, dict[str, object]] = {
    "face1": {"n_frames": 10, "rotation_range_deg": 30.0, "rotation_frequency": "low"},
    "face2": {"n_frames": 10, "rotation_range_deg": 90.0, "rotation_frequency": "low"},
    "face3": {"n_frames": 99, "rotation_range_deg": 30.0, "rotation_frequency": "high"},
    "face4": {"n_frames": 99, "rotation_range_deg": 30.0, "rotation_frequency": "low"},
}


def make_sequence(
    name: str,
    *,
    n_frames: int | None = None,
    n_points: int | None = None,
    noise: float = 0.0,
    seed: int = 0,
) -> Sequence:
    """Generate a named benchmark sequence.

    Parameters
    ----------
    name : str
        One of :data:`SEQUENCE_NAMES`: ``face1`` (10 frames, +-30 degrees), ``face2``
        (10 frames, +-90 degrees), ``face3`` (99 frames, high rotation frequency), ``face4``
        (99 frames, low rotation frequency), all 28,880 points; ``paper`` and ``cloth``
        (60 frames, 10,000 points); or one of :data:`HARD_SEQUENCE_NAMES`: ``flag-osc``,
        ``flag-turn``, ``roll-osc``, ``roll-turn``, ``bumps-osc``, ``bumps-turn`` (60
        frames, 10,000 points; the deformation, then the camera motion).
    n_frames : int, optional
        Overrides the benchmark's number of frames.
    n_points : int, optional
        Overrides the benchmark's number of points.
    noise : float, default 0.0
        Noise level ``lambda_g`` added to the tracks by :func:`add_noise`.
    seed : int, default 0
        Seed of the sequence and of the noise.

    Returns
    -------
    sequence : Sequence
    """
    if name in _FACE_BENCHMARKS:
        settings = dict(_FACE_BENCHMARKS[name])
        if n_frames is not None:
            settings["n_frames"] = n_frames
        if n_points is not None:
            settings["n_points"] = n_points
        sequence = face_sequence(**settings, seed=seed, name=name)  # type: ignore[arg-type]
    elif name in ("paper", "cloth"):
        generator = paper_sequence if name == "paper" else cloth_sequence
        sizes = {"n_frames": n_frames, "n_points": n_points}
        sequence = generator(**{k: v for k, v in sizes.items() if v is not None}, seed=seed)
    elif name in HARD_SEQUENCE_NAMES:
        deformation, camera = name.split("-")
        sizes = {"n_frames": n_frames, "n_points": n_points}
        sequence = HARD_GENERATORS[deformation](
            **{k: v for k, v in sizes.items() if v is not None},
            camera=camera,  # type: ignore[arg-type]
            seed=seed,
        )
    elif name in BODY_SEQUENCE_NAMES:
        sizes = {"n_frames": n_frames, "n_points": n_points}
        sequence = body_sequence(
            **{k: v for k, v in sizes.items() if v is not None},
            camera=name.split("-")[1],  # type: ignore[arg-type]
            seed=seed,
        )
    else:
        known = SEQUENCE_NAMES + HARD_SEQUENCE_NAMES + BODY_SEQUENCE_NAMES
        raise ValueError(f"name must be one of {known}, got {name!r}")
    if noise == 0:
        return sequence
    noisy = add_noise(sequence.W, noise, seed=seed)
    return Sequence(
        sequence.name,
        noisy,
        sequence.rotations,
        sequence.shapes,
        sequence.translations,
        sequence.faces,
        sequence.colors,
        noise=float(noise),
    )
