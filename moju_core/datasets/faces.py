"""The face-like sequences (``face1`` .. ``face4``): a dense face surface with changing
expressions and a non-linear jaw, seen by a moving camera.
"""

from __future__ import annotations

import numpy as np

from moju_core.datasets._assembly import check_sizes, finish, streams
from moju_core.datasets._camera_paths import RotationFrequency, camera_rotations
from moju_core.datasets.sequence import Sequence
from moju_core.datasets.surfaces import (
    gaussian,
    parameter_grid,
    ramp_colors,
    sigmoid,
    smooth_signals,
)


def _face_surface(n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Neutral face: points (P, 3) on an elliptical height field, and its mesh.

    The unit square grid is mapped onto an ellipse of half-width 1 and half-height 1.3 (the
    elliptical grid mapping keeps the grid topology, so the mesh stays valid); y points up,
    z towards the camera at zero rotation.
    """
    u, v, faces = parameter_grid(n_points, aspect=1.0 / 1.3)
    a, b = 2.0 * u - 1.0, 2.0 * v - 1.0
    x = a * np.sqrt(1.0 - 0.5 * b**2)
    y = 1.3 * b * np.sqrt(1.0 - 0.5 * a**2)

    radius2 = x**2 + (y / 1.3) ** 2
    z = 0.6 * np.sqrt(1.0 - 0.9 * radius2)  # dome, still sloped (not vertical) at the rim
    z += 0.10 * gaussian(x, y, 0.0, 0.75, 0.45, 0.25)  # forehead
    z += 0.30 * gaussian(x, y, 0.0, 0.08, 0.08, 0.25)  # nose ridge
    z += 0.18 * gaussian(x, y, 0.0, -0.18, 0.11, 0.09)  # nose tip
    for side in (-1.0, 1.0):
        z -= 0.12 * gaussian(x, y, side * 0.38, 0.28, 0.16, 0.10)  # eye socket
        z += 0.06 * gaussian(x, y, side * 0.38, 0.48, 0.22, 0.06)  # brow ridge
        z += 0.07 * gaussian(x, y, side * 0.50, -0.22, 0.20, 0.20)  # cheek
    z += 0.05 * gaussian(x, y, 0.0, -0.50, 0.20, 0.05)  # upper lip
    z += 0.05 * gaussian(x, y, 0.0, -0.66, 0.18, 0.05)  # lower lip
    z += 0.08 * gaussian(x, y, 0.0, -0.98, 0.25, 0.12)  # chin
    return x, y, z, faces


def _face_expressions(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Five linear expression fields and the lower-face mask of the jaw.

    Returns
    -------
    fields : ndarray of shape (5, P, 3), float64
        Displacements (object units) for smile, mouth open, brow raise, cheek puff and jaw
        shift at full activation; peaks are 0.14-0.22, i.e. 7-11 % of the face width.
    lower_face : ndarray of shape (P,), float64
        Smooth 0-1 mask of the part below the mouth, which the jaw carries.
    """
    n_points = x.shape[0]
    fields = np.zeros((5, n_points, 3))
    mouth_line = -0.58
    lower_face = sigmoid((mouth_line - y) / 0.03)

    # Smile: mouth corners pulled out, up and back; cheeks lifted.
    for side in (-1.0, 1.0):
        corner = gaussian(x, y, side * 0.32, mouth_line, 0.14, 0.12)
        cheek = gaussian(x, y, side * 0.45, -0.28, 0.20, 0.18)
        fields[0, :, 0] += side * 0.14 * corner
        fields[0, :, 1] += 0.10 * corner + 0.06 * cheek
        fields[0, :, 2] += -0.04 * corner + 0.03 * cheek

    # Mouth open: lower lip and chin drop, upper lip lifts a little.
    fields[1, :, 1] = -0.22 * lower_face * gaussian(x, y, 0.0, -0.80, 0.45, 0.35)
    fields[1, :, 1] += 0.04 * (1.0 - lower_face) * gaussian(x, y, 0.0, -0.50, 0.20, 0.07)

    # Brow raise: brows and forehead move up and slightly forward.
    for side in (-1.0, 1.0):
        brow = gaussian(x, y, side * 0.38, 0.55, 0.25, 0.15)
        fields[2, :, 1] += 0.15 * brow
        fields[2, :, 2] += 0.03 * brow

    # Cheek puff: cheeks bulge forward and outward.
    for side in (-1.0, 1.0):
        cheek = gaussian(x, y, side * 0.50, -0.38, 0.20, 0.20)
        fields[3, :, 0] += side * 0.08 * cheek
        fields[3, :, 2] += 0.20 * cheek

    # Jaw shift: the lower face slides sideways.
    fields[4, :, 0] = 0.18 * lower_face * gaussian(x, y, 0.0, -0.90, 0.70, 0.50)
    return fields, lower_face


def face_sequence(
    n_frames: int = 10,
    n_points: int = 28_880,
    rotation_range_deg: float = 30.0,
    rotation_frequency: RotationFrequency = "low",
    seed: int = 0,
    *,
    name: str = "face",
) -> Sequence:
    """A dense face-like surface with changing expressions, seen by a moving camera.

    The neutral face (width 2, height 2.6) is a dome with forehead, nose ridge and tip, eye
    sockets, brows, cheeks, lips and chin. Five expression fields (smile, mouth open, brow
    raise, cheek puff, jaw shift) are mixed with smooth random weights, so the shape
    sequence is close to low rank; a jaw rotation of up to 10 degrees driven by the square
    of the mouth-open weight adds a small non-linear part.

    Parameters
    ----------
    n_frames : int, default 10
        Number of frames F (>= 2).
    n_points : int, default 28880
        Number of points P (>= 4), the first P of a grid over the face.
    rotation_range_deg : float, default 30.0
        Yaw amplitude in degrees: yaw spans +-range; pitch spans about a third of it and roll
        at most 5 degrees, at other frequencies.
    rotation_frequency : {"low", "high"}, default "low"
        About 1 ("low") or 3 ("high") yaw cycles over the sequence; short sequences (fewer
        than 20 frames per cycle) get fewer cycles, down to a single sweep.
    seed : int, default 0
        Seed of the expression weights, camera phases and image translations.
    name : str, default "face"
        Name stored in the result.

    Returns
    -------
    sequence : Sequence
    """
    check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = streams(seed)
    x, y, z, faces = _face_surface(n_points)
    fields, lower_face = _face_expressions(x, y)

    times = np.linspace(0.0, 1.0, n_frames)
    signals = smooth_signals(deformation_rng, times, 5, cycles=(0.5, 2.0))
    weights = signals.copy()
    # Smile, mouth opening and cheek puff only act one way; brow and jaw shift go both ways.
    for one_sided in (0, 1, 3):
        weights[:, one_sided] = 0.5 * (1.0 + signals[:, one_sided])

    rest = np.stack([x, y, z], axis=1)
    # (F, K) @ (K, 3P) through BLAS; far cheaper than an einsum over (F, P, 3).
    shapes = (weights @ fields.reshape(5, -1)).reshape(n_frames, n_points, 3)
    shapes += rest

    # Jaw rotation about the x axis through the jaw hinge; chin goes down and back. Non-linear
    # in the weight (angle ~ weight^2, and cos/sin of the angle).
    angles = np.radians(10.0) * weights[:, 1] ** 2
    hinge_y, hinge_z = -0.05, -0.60
    dy, dz = lower_face * (y - hinge_y), lower_face * (z - hinge_z)
    cos_minus_1, sin = (np.cos(angles) - 1.0)[:, None], np.sin(angles)[:, None]
    shapes[:, :, 1] += cos_minus_1 * dy - sin * dz
    shapes[:, :, 2] += sin * dy + cos_minus_1 * dz

    camera = camera_rotations(n_frames, rotation_range_deg, rotation_frequency, camera_rng)
    colors = ramp_colors(z, low=(150, 100, 80), high=(245, 210, 185))
    return finish(name, shapes, camera, translation_rng, 2.0, faces, colors)
