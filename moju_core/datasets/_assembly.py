"""What every generator shares: argument checks, random streams, the common start of the
sheet generators, and the final step from shapes and cameras to a projected
:class:`~moju_core.datasets.sequence.Sequence` with image translations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from moju_core.cameras import projection
from moju_core.datasets.sequence import Sequence
from moju_core.datasets.surfaces import parameter_grid

# Independent random streams per aspect, so that e.g. the camera path does not change when a
# deformation parameter draws one more number.
_STREAM_DEFORMATION, _STREAM_CAMERA, _STREAM_TRANSLATION = 0, 1, 2


def check_sizes(n_frames: int, n_points: int) -> None:
    """Refuse fewer than 2 frames or 4 points, and non-integer sizes (ValueError)."""
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


def finish(
    name: str,
    shapes: np.ndarray,
    camera: np.ndarray,
    translation_rng: np.random.Generator,
    extent: float,
    faces: np.ndarray | None,
    colors: np.ndarray,
) -> Sequence:
    """Centre the shapes, project them and wrap everything into a :class:`Sequence`."""
    shapes -= shapes.mean(axis=1, keepdims=True)
    rotations = np.ascontiguousarray(camera[:, :2, :])
    translations = _image_translations(shapes.shape[0], extent, translation_rng)
    # Orthographic projection W_f = R_f S_f^T + t_f, stacked to (2F, P).
    image = projection.project(rotations, shapes.transpose(0, 2, 1)) + translations[:, :, None]
    W = image.reshape(2 * shapes.shape[0], shapes.shape[1])
    return Sequence(name, W, rotations, shapes, translations, faces, colors)


def streams(seed: int) -> tuple[np.random.Generator, ...]:
    """The deformation, camera and translation streams of ``seed``, independent of each other."""
    return tuple(
        np.random.default_rng([seed, stream])
        for stream in (_STREAM_DEFORMATION, _STREAM_CAMERA, _STREAM_TRANSLATION)
    )


@dataclass(frozen=True, eq=False)
class SheetStart:
    """What every sheet generator starts from (:func:`sheet_start`).

    Attributes
    ----------
    deformation_rng, camera_rng, translation_rng : numpy.random.Generator
        The independent streams of the deformation, the camera path and the image
        translations (:func:`streams`); :meth:`finish` uses the last.
    u, v : ndarray of shape (P,), float64
        Grid coordinates of the points in [0, 1], u along the sheet's long side
        (:func:`~moju_core.datasets.surfaces.parameter_grid`).
    faces : ndarray of shape (M, 3), int64
        The grid's triangles.
    times : ndarray of shape (F, 1), float64
        Normalised time in [0, 1], a column so that it broadcasts against fields of shape (P,).
    """

    deformation_rng: np.random.Generator
    camera_rng: np.random.Generator
    translation_rng: np.random.Generator
    u: np.ndarray
    v: np.ndarray
    faces: np.ndarray
    times: np.ndarray

    def finish(
        self, name: str, shapes: np.ndarray, camera: np.ndarray, extent: float, colors: np.ndarray
    ) -> Sequence:
        """:func:`finish` with this sheet's translation stream and faces."""
        return finish(name, shapes, camera, self.translation_rng, extent, self.faces, colors)


def sheet_start(n_frames: int, n_points: int, seed: int, aspect: float) -> SheetStart:
    """Check the sizes, draw the random streams of ``seed`` and lay the sheet's point grid.

    Parameters
    ----------
    n_frames : int
        Number of frames F (>= 2).
    n_points : int
        Number of points P (>= 4), the first P of the grid.
    seed : int
    aspect : float
        Length over width of the sheet; the grid has about that many more columns than rows.

    Returns
    -------
    SheetStart
    """
    check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = streams(seed)
    u, v, faces = parameter_grid(n_points, aspect=aspect)
    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    return SheetStart(deformation_rng, camera_rng, translation_rng, u, v, faces, times)
