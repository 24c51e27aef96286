"""What every generator shares: argument checks, random streams, and the final step from
shapes and cameras to a projected :class:`Sequence` with image translations.
"""

from __future__ import annotations

import numpy as np

from moju_core.datasets.sequence import Sequence

# Independent random streams per aspect, so that e.g. the camera path does not change when a
# deformation parameter draws one more number.
_STREAM_DEFORMATION, _STREAM_CAMERA, _STREAM_TRANSLATION = 0, 1, 2


def check_sizes(n_frames: int, n_points: int) -> None:
    if int(n_frames) != n_frames or n_frames < 2:
        raise ValueError(f"n_frames must be an integer >= 2, got {n_frames!r}")
    if int(n_points) != n_points or n_points < 4:
        raise ValueError(f"n_points must be an integer >= 4, got {n_points!r}")


def _image_translations(n_frames: int, extent: float, rng: np.random.Generator) -> np.ndarray:
    """A random image offset (up to a quarter of ``extent``) plus a slow drift, (F, 2)."""
    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    offset = rng.uniform(-0.25, 0.25, size=2) * extent
    phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
    return offset + 0.05 * extent * np.sin(2.0 * np.pi * times + phases)


def _project(rotations: np.ndarray, shapes: np.ndarray, translations: np.ndarray) -> np.ndarray:
    """Orthographic projection ``W_f = R_f S_f^T + t_f`` stacked to (2F, P)."""
    n_frames, n_points = shapes.shape[:2]
    image = rotations @ shapes.transpose(0, 2, 1)
    image += translations[:, :, None]
    return image.reshape(2 * n_frames, n_points)


def finish(
    name: str,
    shapes: np.ndarray,
    camera: np.ndarray,
    translation_rng: np.random.Generator,
    extent: float,
    faces: np.ndarray,
    colors: np.ndarray,
) -> Sequence:
    """Centre the shapes, project them and wrap everything into a :class:`Sequence`."""
    shapes -= shapes.mean(axis=1, keepdims=True)
    rotations = np.ascontiguousarray(camera[:, :2, :])
    translations = _image_translations(shapes.shape[0], extent, translation_rng)
    W = _project(rotations, shapes, translations)
    return Sequence(name, W, rotations, shapes, translations, faces, colors)


def streams(seed: int) -> tuple[np.random.Generator, ...]:
    return tuple(
        np.random.default_rng([seed, stream])
        for stream in (_STREAM_DEFORMATION, _STREAM_CAMERA, _STREAM_TRANSLATION)
    )
