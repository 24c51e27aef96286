"""Synthetic dense NRSfM sequences with ground truth, built to resemble the paper's benchmarks.

The paper's data (Garg et al.'s synthetic faces, the paper and T-shirt captures) cannot be
redistributed, so this module generates look-alikes:

* ``face1`` .. ``face4``: a dense face-like surface (28,880 points) animated by five smooth
  expression fields and a non-linear jaw rotation; 10 frames at +-30 and +-90 degrees of yaw,
  and 99 frames at high and low rotation frequency. With the same ``seed`` the four share one
  expression sequence per length, as the original benchmarks share one facial performance.
* ``paper``: an inextensible sheet that bends and then rolls up (isometric by construction).
* ``cloth``: a flag-like sheet with travelling waves and a slowly changing global bend.

The hard sequences (:data:`HARD_SEQUENCE_NAMES`, named ``<deformation>-<camera>``) have
large deformations that no single rigid shape approximates (best rigid e3D, per-frame
Procrustes, between 0.13 and 0.34 for seeds 0-4 at 10,000 points), 60 frames and 10,000
points by default:

* ``flag-*``: a flag pinned along one edge with two travelling waves shorter than the flag
  (wavelengths 0.5-0.85 of its length, amplitudes 10-12 % of it at the free edge).
* ``roll-*``: a sheet that rolls up isometrically into a spiral of 1.2-1.5 turns.
* ``bumps-*``: a sheet with a 4 x 4 grid of Gaussian bumps whose heights (up to 21 % of
  the side) rise and sink into dents, neighbours half a cycle out of phase.

Each under two camera motions: ``osc``, a camera oscillating +-40 degrees in yaw with a period
of 30 frames (and +-12 degrees of pitch, period 51 frames); ``turn``, a slow turntable that
spins the sheet about its rest normal by 3 degrees per frame, seen 45 +- 5 degrees off that
normal. The seed changes the deformation's phases and directions and the camera's phase (and
the turntable's sense); one seed gives the same deformation under both cameras.

Every sequence is an orthographic projection ``W_f = R_f S_f + t_f`` of the true shapes, with
per-frame image translations ``t_f`` so that translation removal is exercised; lengths are in
"object units" (face width 2, sheet lengths about 2 and 1.4), the image is in the same units.
The noise protocol of the paper (Gaussian noise of standard deviation ``lambda_g * max|W|``)
is :func:`add_noise`. Everything is deterministic given ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from moju_core.cameras import projection

RotationFrequency = Literal["low", "high"]

SEQUENCE_NAMES: tuple[str, ...] = ("face1", "face2", "face3", "face4", "paper", "cloth")

# Yaw cycles over a whole sequence; short sequences are capped (see _yaw_cycles).
_YAW_CYCLES = {"low": 1.0, "high": 3.0}
# Fewer frames than this per yaw cycle would alias the oscillation into jumps between frames.
_MIN_FRAMES_PER_CYCLE = 20.0

# Camera yaw range of the paper and cloth sequences, swept three times. Orthographic NRSfM
# recovers depth only where the camera moves fast relative to the deformation (Akhter et al.'s
# trajectory-space argument): with one slow +-30 degree sweep, as on the faces, no
# factorisation method did better on the rolling sheet than its best rigid approximation
# (measured: bmm with known rotations e3D 0.17 on paper and 0.25 on cloth, rigid 0.19 and
# 0.23), so those sequences would test nothing. Real captures of paper and cloth (e.g. the
# kinect paper and T-shirt sequences) have a hand-held camera moving around the object.
_SHEET_CAMERA_RANGE_DEG = 60.0

# Independent random streams per aspect, so that e.g. the camera path does not change when a
# deformation parameter draws one more number.
_STREAM_DEFORMATION, _STREAM_CAMERA, _STREAM_TRANSLATION = 0, 1, 2


@dataclass(frozen=True, eq=False)
class Sequence:
    """A synthetic sequence and its ground truth.

    Attributes
    ----------
    name : str
        Sequence name, e.g. ``"face3"``.
    W : ndarray of shape (2F, P), float64
        Image tracks; rows ``2f`` and ``2f + 1`` are x and y of frame f (object units),
        ``W_f = R_f S_f^T + t_f`` plus noise when ``noise > 0``.
    rotations : ndarray of shape (F, 2, 3), float64
        True camera rotations (orthonormal rows).
    shapes : ndarray of shape (F, P, 3), float64
        True 3D shapes in the world frame, each frame centred on its centroid.
    translations : ndarray of shape (F, 2), float64
        Image translations that were added to the projections.
    faces : ndarray of shape (M, 3), int64, or None
        Triangles over the points (indices into P), for mesh export.
    colors : ndarray of shape (P, 3), uint8
        A per-point colour (shading by height or by surface coordinate).
    noise : float, default 0.0
        The noise level ``lambda_g`` that was added to ``W`` (see :func:`add_noise`).
    """

    name: str
    W: np.ndarray
    rotations: np.ndarray
    shapes: np.ndarray
    translations: np.ndarray
    faces: np.ndarray | None
    colors: np.ndarray
    noise: float = 0.0

    def __post_init__(self) -> None:
        n_frames, n_points = self.shapes.shape[:2]
        expected = {
            "W": (self.W.shape, (2 * n_frames, n_points)),
            "rotations": (self.rotations.shape, (n_frames, 2, 3)),
            "shapes": (self.shapes.shape, (n_frames, n_points, 3)),
            "translations": (self.translations.shape, (n_frames, 2)),
            "colors": (self.colors.shape, (n_points, 3)),
        }
        for field_name, (actual, wanted) in expected.items():
            if actual != wanted:
                raise ValueError(f"{field_name} must have shape {wanted}, got {actual}")
        if self.faces is not None and (self.faces.ndim != 2 or self.faces.shape[1] != 3):
            raise ValueError(f"faces must have shape (M, 3), got {self.faces.shape}")

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.shapes.shape[0])

    @property
    def n_points(self) -> int:
        """Number of tracked points P."""
        return int(self.shapes.shape[1])

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The sequence under the dataset names of the project's input file contract.

        Returns
        -------
        arrays : dict of str to ndarray
            ``W`` (2F, P), ``R`` (F, 2, 3), ``gt`` (F, P, 3), ``colors`` (P, 3) and, when
            there is a mesh, ``faces`` (M, 3).
        """
        arrays = {"W": self.W, "R": self.rotations, "gt": self.shapes, "colors": self.colors}
        if self.faces is not None:
            arrays["faces"] = self.faces
        return arrays


# --- building blocks -----------------------------------------------------------------------


def _check_sizes(n_frames: int, n_points: int) -> None:
    if int(n_frames) != n_frames or n_frames < 2:
        raise ValueError(f"n_frames must be an integer >= 2, got {n_frames!r}")
    if int(n_points) != n_points or n_points < 4:
        raise ValueError(f"n_points must be an integer >= 4, got {n_points!r}")


def _parameter_grid(n_points: int, aspect: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first ``n_points`` of a row-major grid over the unit square, and its triangles.

    The grid has about ``aspect`` times more columns than rows, so cells are nearly square
    on a surface ``aspect`` times wider than tall; its last row may be partial.

    Returns
    -------
    u, v : ndarray of shape (P,), float64
        Column and row coordinates in [0, 1].
    faces : ndarray of shape (M, 3), int64
        Two triangles per grid cell, kept when all three corners exist.
    """
    n_cols = max(2, round(np.sqrt(n_points * aspect)))
    # At least two rows, so that even tiny grids are not collinear.
    n_cols = min(n_cols, n_points // 2)
    n_rows = -(-n_points // n_cols)
    index = np.arange(n_points)
    u = (index % n_cols) / (n_cols - 1)
    v = (index // n_cols) / (n_rows - 1)

    rows, cols = np.meshgrid(np.arange(n_rows - 1), np.arange(n_cols - 1), indexing="ij")
    corner = (rows * n_cols + cols).ravel()
    lower = np.stack([corner, corner + 1, corner + n_cols], axis=1)
    upper = np.stack([corner + 1, corner + n_cols + 1, corner + n_cols], axis=1)
    triangles = np.concatenate([lower, upper])
    faces = triangles[triangles.max(axis=1) < n_points]
    return u, v, faces.astype(np.int64)


def _gaussian(
    x: np.ndarray, y: np.ndarray, cx: float, cy: float, sx: float, sy: float
) -> np.ndarray:
    """Axis-aligned anisotropic Gaussian bump of height 1 centred at (cx, cy), (P,)."""
    return np.exp(-0.5 * (((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))


def _sigmoid(values: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * values))


def _smooth_signals(
    rng: np.random.Generator, times: np.ndarray, n_signals: int, cycles: tuple[float, float]
) -> np.ndarray:
    """Smooth random signals spanning [-1, 1]: sums of two sinusoids, random frequencies.

    Parameters
    ----------
    times : ndarray of shape (F,)
        Normalised time in [0, 1].
    cycles : (float, float)
        Range of the frequencies, in cycles per sequence.

    Returns
    -------
    signals : ndarray of shape (F, n_signals), float64
    """
    frequencies = rng.uniform(*cycles, size=(2, n_signals))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(2, n_signals))
    amplitudes = rng.uniform(0.5, 1.0, size=(2, n_signals))
    waves = amplitudes * np.sin(2.0 * np.pi * frequencies * times[:, None, None] + phases)
    signals = waves.sum(axis=1)
    # Stretch every signal to span [-1, 1] exactly, so that every expression reaches full
    # activation whatever the seed and the sequence length.
    low, high = signals.min(axis=0), signals.max(axis=0)
    span = np.where(high > low, high - low, 1.0)
    return 2.0 * (signals - low) / span - 1.0


def _axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    """Right-handed rotations by ``angles`` (radians, (F,)) about a coordinate axis, (F, 3, 3)."""
    cos, sin = np.cos(angles), np.sin(angles)
    i, j = [k for k in range(3) if k != axis]
    if axis == 1:
        # Keeps the cyclic order z -> x so that the rotation about y is right-handed.
        i, j = j, i
    rotations = np.zeros((angles.shape[0], 3, 3))
    rotations[:, axis, axis] = 1.0
    rotations[:, i, i] = cos
    rotations[:, j, j] = cos
    rotations[:, i, j] = -sin
    rotations[:, j, i] = sin
    return rotations


def _yaw_cycles(n_frames: int, frequency: RotationFrequency) -> float:
    """Yaw cycles over the sequence; short sequences get a single sweep (half a cycle)."""
    if frequency not in _YAW_CYCLES:
        raise ValueError(
            f"rotation_frequency must be one of {tuple(_YAW_CYCLES)}, got {frequency!r}"
        )
    affordable = (n_frames - 1) / _MIN_FRAMES_PER_CYCLE
    return min(_YAW_CYCLES[frequency], max(0.5, affordable))


def _camera_rotations(
    n_frames: int, range_deg: float, frequency: RotationFrequency, rng: np.random.Generator
) -> np.ndarray:
    """Camera path ``R_f = Rz(roll) Rx(pitch) Ry(yaw)``, returned as full rotations (F, 3, 3).

    Yaw is ``-range cos(2 pi c t)`` so it reaches both ends of +-range; pitch (a third of the
    range) and a small roll run at other frequencies with random phases, so the motion is not
    about a single axis (which would leave depth undetermined).
    """
    if not 0.0 <= range_deg <= 180.0:
        raise ValueError(f"rotation_range_deg must be in [0, 180], got {range_deg!r}")
    times = np.linspace(0.0, 1.0, n_frames)
    cycles = _yaw_cycles(n_frames, frequency)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
    yaw = -range_deg * np.cos(2.0 * np.pi * cycles * times)
    pitch = range_deg / 3.0 * np.sin(2.0 * np.pi * (0.6 * cycles + 0.35) * times + phases[0])
    roll = min(5.0, range_deg / 6.0) * np.sin(
        2.0 * np.pi * (0.4 * cycles + 0.55) * times + phases[1]
    )
    return (
        _axis_rotations(2, np.radians(roll))
        @ _axis_rotations(0, np.radians(pitch))
        @ _axis_rotations(1, np.radians(yaw))
    )


def _image_translations(n_frames: int, extent: float, rng: np.random.Generator) -> np.ndarray:
    """A random image offset (up to a quarter of ``extent``) plus a slow drift, (F, 2)."""
    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    offset = rng.uniform(-0.25, 0.25, size=2) * extent
    phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
    return offset + 0.05 * extent * np.sin(2.0 * np.pi * times + phases)


def _ramp_colors(values: np.ndarray, low: tuple[int, int, int], high: tuple[int, int, int]):
    """Linear colour ramp between two RGB colours over the range of ``values``, (P, 3) uint8."""
    span = np.ptp(values)
    weights = (values - values.min()) / span if span > 0 else np.zeros_like(values)
    colors = np.asarray(low) + weights[:, None] * (np.asarray(high) - np.asarray(low))
    return np.round(colors).astype(np.uint8)


def _finish(
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
    # Orthographic projection W_f = R_f S_f^T + t_f, stacked to (2F, P).
    image = projection.project(rotations, shapes.transpose(0, 2, 1)) + translations[:, :, None]
    W = image.reshape(2 * shapes.shape[0], shapes.shape[1])
    return Sequence(name, W, rotations, shapes, translations, faces, colors)


def _streams(seed: int) -> tuple[np.random.Generator, ...]:
    return tuple(
        np.random.default_rng([seed, stream])
        for stream in (_STREAM_DEFORMATION, _STREAM_CAMERA, _STREAM_TRANSLATION)
    )


# --- face ----------------------------------------------------------------------------------


def _face_surface(n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Neutral face: points (P, 3) on an elliptical height field, and its mesh.

    The unit square grid is mapped onto an ellipse of half-width 1 and half-height 1.3 (the
    elliptical grid mapping keeps the grid topology, so the mesh stays valid); y points up,
    z towards the camera at zero rotation.
    """
    u, v, faces = _parameter_grid(n_points, aspect=1.0 / 1.3)
    a, b = 2.0 * u - 1.0, 2.0 * v - 1.0
    x = a * np.sqrt(1.0 - 0.5 * b**2)
    y = 1.3 * b * np.sqrt(1.0 - 0.5 * a**2)

    radius2 = x**2 + (y / 1.3) ** 2
    z = 0.6 * np.sqrt(1.0 - 0.9 * radius2)  # dome, still sloped (not vertical) at the rim
    z += 0.10 * _gaussian(x, y, 0.0, 0.75, 0.45, 0.25)  # forehead
    z += 0.30 * _gaussian(x, y, 0.0, 0.08, 0.08, 0.25)  # nose ridge
    z += 0.18 * _gaussian(x, y, 0.0, -0.18, 0.11, 0.09)  # nose tip
    for side in (-1.0, 1.0):
        z -= 0.12 * _gaussian(x, y, side * 0.38, 0.28, 0.16, 0.10)  # eye socket
        z += 0.06 * _gaussian(x, y, side * 0.38, 0.48, 0.22, 0.06)  # brow ridge
        z += 0.07 * _gaussian(x, y, side * 0.50, -0.22, 0.20, 0.20)  # cheek
    z += 0.05 * _gaussian(x, y, 0.0, -0.50, 0.20, 0.05)  # upper lip
    z += 0.05 * _gaussian(x, y, 0.0, -0.66, 0.18, 0.05)  # lower lip
    z += 0.08 * _gaussian(x, y, 0.0, -0.98, 0.25, 0.12)  # chin
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
    lower_face = _sigmoid((mouth_line - y) / 0.03)

    # Smile: mouth corners pulled out, up and back; cheeks lifted.
    for side in (-1.0, 1.0):
        corner = _gaussian(x, y, side * 0.32, mouth_line, 0.14, 0.12)
        cheek = _gaussian(x, y, side * 0.45, -0.28, 0.20, 0.18)
        fields[0, :, 0] += side * 0.14 * corner
        fields[0, :, 1] += 0.10 * corner + 0.06 * cheek
        fields[0, :, 2] += -0.04 * corner + 0.03 * cheek

    # Mouth open: lower lip and chin drop, upper lip lifts a little.
    fields[1, :, 1] = -0.22 * lower_face * _gaussian(x, y, 0.0, -0.80, 0.45, 0.35)
    fields[1, :, 1] += 0.04 * (1.0 - lower_face) * _gaussian(x, y, 0.0, -0.50, 0.20, 0.07)

    # Brow raise: brows and forehead move up and slightly forward.
    for side in (-1.0, 1.0):
        brow = _gaussian(x, y, side * 0.38, 0.55, 0.25, 0.15)
        fields[2, :, 1] += 0.15 * brow
        fields[2, :, 2] += 0.03 * brow

    # Cheek puff: cheeks bulge forward and outward.
    for side in (-1.0, 1.0):
        cheek = _gaussian(x, y, side * 0.50, -0.38, 0.20, 0.20)
        fields[3, :, 0] += side * 0.08 * cheek
        fields[3, :, 2] += 0.20 * cheek

    # Jaw shift: the lower face slides sideways.
    fields[4, :, 0] = 0.18 * lower_face * _gaussian(x, y, 0.0, -0.90, 0.70, 0.50)
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
    _check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = _streams(seed)
    x, y, z, faces = _face_surface(n_points)
    fields, lower_face = _face_expressions(x, y)

    times = np.linspace(0.0, 1.0, n_frames)
    signals = _smooth_signals(deformation_rng, times, 5, cycles=(0.5, 2.0))
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

    camera = _camera_rotations(n_frames, rotation_range_deg, rotation_frequency, camera_rng)
    colors = _ramp_colors(z, low=(150, 100, 80), high=(245, 210, 185))
    return _finish(name, shapes, camera, translation_rng, 2.0, faces, colors)


# --- paper ---------------------------------------------------------------------------------


def _cumulative_trapezoid(values: np.ndarray, step: float) -> np.ndarray:
    """Running integral along the last axis on a uniform grid, starting at 0, same shape."""
    integral = np.zeros_like(values)
    integral[..., 1:] = np.cumsum(0.5 * step * (values[..., 1:] + values[..., :-1]), axis=-1)
    return integral


def _bend_sheet(curvature: np.ndarray, step: float, u: np.ndarray) -> np.ndarray:
    """Points of an inextensible plane curve with the given curvature, by arc length.

    Integrates ``theta = int kappa ds``, ``x = int cos(theta) ds``, ``z = int sin(theta) ds``
    on the samples, then interpolates every frame's curve linearly at the points' arc
    lengths (the weights are shared by all frames because the samples are).

    Parameters
    ----------
    curvature : ndarray of shape (F, K), float64
        Curvature (1 / object units) on K uniform arc-length samples, ``step`` apart.
    step : float
        Sample spacing (object units); the curve's length is ``(K - 1) * step``.
    u : ndarray of shape (P,)
        The points' arc lengths as fractions of the curve's length, in [0, 1].

    Returns
    -------
    curve : ndarray of shape (F, P, 2), float64
        In-plane (x) and out-of-plane (z) coordinates, starting at the origin along +x.
    """
    n_samples = curvature.shape[1]
    tangent_angle = _cumulative_trapezoid(curvature, step)
    curve_x = _cumulative_trapezoid(np.cos(tangent_angle), step)
    curve_z = _cumulative_trapezoid(np.sin(tangent_angle), step)
    position = u * (n_samples - 1)
    left = np.minimum(position.astype(np.int64), n_samples - 2)
    fraction = position - left
    return np.stack(
        [c[:, left] * (1.0 - fraction) + c[:, left + 1] * fraction for c in (curve_x, curve_z)],
        axis=-1,
    )


def paper_sequence(n_frames: int = 60, n_points: int = 10_000, seed: int = 0) -> Sequence:
    """A sheet of paper (2 x 1.43, aspect 1.4) that bends and then rolls up, isometrically.

    The sheet is a developable surface with straight generators along its short side: its
    cross-section is a plane curve with arc length ``s`` along the long side and curvature
    ``kappa(s, t)``; integrating ``theta = int kappa ds``, ``x = int cos(theta) ds``,
    ``z = int sin(theta) ds`` on a fine grid gives a curve of exactly the sheet's length, so
    the paper never stretches. The curvature mixes a transient S-shaped bend (peaking in
    mid-sequence) with a roll at the far end whose total turn grows smoothly from 0 to
    200-240 degrees while its start moves from 85 % to 40 % of the length. The camera yaws
    +-60 degrees (three cycles) with some pitch and roll (see ``_SHEET_CAMERA_RANGE_DEG``).

    Parameters
    ----------
    n_frames : int, default 60
        Number of frames F (>= 2).
    n_points : int, default 10000
        Number of points P (>= 4), the first P of a grid over the sheet.
    seed : int, default 0
        Seed of the bend amplitudes, camera phases and image translations.

    Returns
    -------
    sequence : Sequence
    """
    _check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = _streams(seed)
    length, width = 2.0, 2.0 / 1.4
    u, v, faces = _parameter_grid(n_points, aspect=1.4)

    final_turn = np.radians(deformation_rng.uniform(200.0, 240.0))
    s_bend = deformation_rng.uniform(0.25, 0.40)  # half the peak tangent angle, radians

    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    progress = times**2 * (3.0 - 2.0 * times)  # smoothstep: rolling starts and ends gently
    # 2049 samples keep the polyline's chord error far below anything a test can see.
    s = np.linspace(0.0, length, 2049)
    step = s[1] - s[0]
    roll_start = length * (0.85 - 0.45 * progress)
    roll_profile = _sigmoid((s - roll_start) / (0.04 * length))
    roll_profile /= _cumulative_trapezoid(roll_profile, step)[:, -1:]
    curvature = final_turn * progress * roll_profile
    curvature += (
        s_bend * np.sin(np.pi * times) * (2.0 * np.pi / length) * np.sin(2.0 * np.pi * s / length)
    )
    curve = _bend_sheet(curvature, step, u)
    shapes = np.empty((n_frames, n_points, 3))
    shapes[:, :, 0] = curve[..., 0]
    shapes[:, :, 2] = curve[..., 1]
    shapes[:, :, 1] = v * width

    camera = _camera_rotations(n_frames, _SHEET_CAMERA_RANGE_DEG, "high", camera_rng)
    colors = _ramp_colors(u, low=(235, 235, 225), high=(120, 160, 220))
    return _finish("paper", shapes, camera, translation_rng, length, faces, colors)


# --- cloth ---------------------------------------------------------------------------------


def cloth_sequence(n_frames: int = 60, n_points: int = 10_000, seed: int = 0) -> Sequence:
    """A waving cloth (1.4 x 1): travelling waves plus a slowly changing global bend.

    Three sinusoidal waves with different directions, wavelengths of 0.7-1.4 (half to all of
    the cloth's length), amplitudes of 0.14-0.22 (10-16 % of the length) travel across the
    cloth, each moving 1-2 wavelengths over the sequence. Like a flag on a pole their
    amplitude grows from the left edge (25 %) to the right edge (100 %), and they carry a
    small in-plane component (water-wave style). A global bend along the long side changes
    slowly. The camera yaws +-60 degrees (three cycles) with some pitch and roll (see
    ``_SHEET_CAMERA_RANGE_DEG``).

    Parameters
    ----------
    n_frames : int, default 60
        Number of frames F (>= 2).
    n_points : int, default 10000
        Number of points P (>= 4), the first P of a grid over the cloth.
    seed : int, default 0
        Seed of the wave parameters, camera phases and image translations.

    Returns
    -------
    sequence : Sequence
    """
    _check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = _streams(seed)
    length, height = 1.4, 1.0
    u, v, faces = _parameter_grid(n_points, aspect=length / height)
    x, y = u * length, v * height

    directions = np.array([0.0, 1.0, -1.4]) + deformation_rng.uniform(-0.3, 0.3, size=3)
    wavelengths = deformation_rng.uniform(0.5, 1.0, size=3) * length
    amplitudes = deformation_rng.uniform(0.10, 0.16, size=3) * length
    travel = deformation_rng.uniform(1.0, 2.0, size=3)  # wavelengths per sequence
    phases = deformation_rng.uniform(0.0, 2.0 * np.pi, size=3)
    bend_phase = deformation_rng.uniform(0.0, 2.0 * np.pi)

    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    envelope = 0.25 + 0.75 * u
    shapes = np.zeros((n_frames, n_points, 3))
    shapes[:, :, 0] = x
    shapes[:, :, 1] = y
    for k in range(3):
        direction = np.array([np.cos(directions[k]), np.sin(directions[k])])
        along = x * direction[0] + y * direction[1]
        phase = 2.0 * np.pi * (along / wavelengths[k] - travel[k] * times) + phases[k]
        shapes[:, :, 2] += amplitudes[k] * envelope * np.sin(phase)
        # A third of the amplitude in-plane, along the wave, a quarter period out of step.
        in_plane = -0.3 * amplitudes[k] * envelope * np.cos(phase)
        shapes[:, :, 0] += in_plane * direction[0]
        shapes[:, :, 1] += in_plane * direction[1]
    bend = 0.3 * np.sin(2.0 * np.pi * 0.5 * times + bend_phase)
    shapes[:, :, 2] += bend * (2.0 * u - 1.0) ** 2

    camera = _camera_rotations(n_frames, _SHEET_CAMERA_RANGE_DEG, "high", camera_rng)
    colors = _ramp_colors(x + 0.5 * y, low=(170, 30, 40), high=(250, 200, 70))
    return _finish("cloth", shapes, camera, translation_rng, length, faces, colors)


# --- hard sequences: large deformations under two camera motions ---------------------------

CameraMotion = Literal["osc", "turn"]
CAMERA_MOTIONS: tuple[str, ...] = ("osc", "turn")

# Oscillating camera: yaw +-40 degrees with a period of 30 frames, pitch +-12 degrees with a
# period of 51 frames (so the motion is not about one axis), random phases.
_OSC_YAW_DEG, _OSC_PERIOD_FRAMES = 40.0, 30.0
_OSC_PITCH_DEG, _OSC_PITCH_PERIOD_FRAMES = 12.0, 51.0
# Turntable: the sheet spins about its own normal by 3 degrees per frame (random start and
# sense) and is seen 45 degrees off its normal, the tilt wobbling by +-5 degrees over the
# sequence; a sheet on a turntable filmed from above at an angle.
_TURN_RATE_DEG, _TURN_TILT_DEG, _TURN_WOBBLE_DEG = 3.0, 45.0, 5.0


def _hard_camera(n_frames: int, motion: CameraMotion, rng: np.random.Generator) -> np.ndarray:
    """Camera path of the hard sequences, full rotations (F, 3, 3); see the constants above.

    ``"osc"``: ``R_f = Rx(pitch_f) Ry(yaw_f)``; ``"turn"``: ``R_f = Rx(tilt_f) Rz(spin_f)``
    (z is the sheets' rest normal, towards the camera at zero rotation).
    """
    if motion not in CAMERA_MOTIONS:
        raise ValueError(f"camera must be one of {CAMERA_MOTIONS}, got {motion!r}")
    frames = np.arange(n_frames, dtype=np.float64)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
    if motion == "osc":
        yaw = _OSC_YAW_DEG * np.sin(2.0 * np.pi * frames / _OSC_PERIOD_FRAMES + phases[0])
        pitch = _OSC_PITCH_DEG * np.sin(2.0 * np.pi * frames / _OSC_PITCH_PERIOD_FRAMES + phases[1])
        return _axis_rotations(0, np.radians(pitch)) @ _axis_rotations(1, np.radians(yaw))
    sense = rng.choice([-1.0, 1.0])
    spin = np.degrees(phases[0]) + sense * _TURN_RATE_DEG * frames
    tilt = _TURN_TILT_DEG + _TURN_WOBBLE_DEG * np.sin(
        2.0 * np.pi * frames / max(n_frames - 1, 1) + phases[1]
    )
    return _axis_rotations(0, np.radians(tilt)) @ _axis_rotations(2, np.radians(spin))


def flag_sequence(
    n_frames: int = 60,
    n_points: int = 10_000,
    camera: CameraMotion = "osc",
    seed: int = 0,
) -> Sequence:
    """A flag (1.4 x 1) pinned along its left edge, with two travelling waves shorter than it.

    Two sinusoidal waves travel away from the pole (directions within +-0.5 rad of the long
    side), with wavelengths of 0.5-0.85 of the flag's length (0.7-1.19), each moving 1.5-3
    wavelengths over the sequence. Each has an amplitude of 10-12 % of the length at the
    free edge; the amplitude grows from zero at the pinned edge as ``1 - (1 - u)^2`` (u: 0
    at the pole, 1 at the free edge). A quarter of each amplitude is in-plane, along the
    wave and a quarter period out of step, so the cloth bunches where it folds. The flag is
    not inextensible: where the two waves add up, grid edges stretch by up to 2-3 times.

    Parameters
    ----------
    n_frames : int, default 60
        Number of frames F (>= 2).
    n_points : int, default 10000
        Number of points P (>= 4), the first P of a grid over the flag.
    camera : {"osc", "turn"}, default "osc"
        Oscillating camera or slow turntable (see :func:`make_sequence`).
    seed : int, default 0
        Seed of the wave directions, wavelengths, phases, the camera phase and the image
        translations.

    Returns
    -------
    sequence : Sequence
    """
    _check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = _streams(seed)
    length, height = 1.4, 1.0
    u, v, faces = _parameter_grid(n_points, aspect=length / height)
    x, y = u * length, v * height

    n_waves = 2
    directions = deformation_rng.uniform(-0.5, 0.5, size=n_waves)
    wavelengths = deformation_rng.uniform(0.5, 0.85, size=n_waves) * length
    amplitudes = deformation_rng.uniform(0.10, 0.12, size=n_waves) * length
    travel = deformation_rng.uniform(1.5, 3.0, size=n_waves)  # wavelengths per sequence
    phases = deformation_rng.uniform(0.0, 2.0 * np.pi, size=n_waves)

    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    envelope = 1.0 - (1.0 - u) ** 2  # zero on the pinned edge u = 0
    shapes = np.zeros((n_frames, n_points, 3))
    shapes[:, :, 0] = x
    shapes[:, :, 1] = y
    for k in range(n_waves):
        direction = np.array([np.cos(directions[k]), np.sin(directions[k])])
        along = x * direction[0] + y * direction[1]
        phase = 2.0 * np.pi * (along / wavelengths[k] - travel[k] * times) + phases[k]
        shapes[:, :, 2] += amplitudes[k] * envelope * np.sin(phase)
        in_plane = -0.25 * amplitudes[k] * envelope * np.cos(phase)
        shapes[:, :, 0] += in_plane * direction[0]
        shapes[:, :, 1] += in_plane * direction[1]

    rotations = _hard_camera(n_frames, camera, camera_rng)
    colors = _ramp_colors(x - 0.3 * y, low=(30, 60, 170), high=(240, 240, 240))
    return _finish(f"flag-{camera}", shapes, rotations, translation_rng, length, faces, colors)


def roll_sequence(
    n_frames: int = 60,
    n_points: int = 10_000,
    camera: CameraMotion = "osc",
    seed: int = 0,
) -> Sequence:
    """A sheet (2 x 1.43) that rolls up into a spiral of 1.2-1.5 turns, isometrically.

    Built like :func:`paper_sequence` (a developable surface integrated from a curvature
    along its long side, so it never stretches), but the roll goes further: its total turn
    grows smoothly from 0 to 430-540 degrees while its start moves from 90 % to 25-35 % of
    the length. Inside the roll the curvature grows linearly towards the free end (to 2.5
    times its value at the start of the roll), so the sheet winds into a spiral instead of
    overlapping itself on one circle. The seed also chooses which end rolls, and whether it
    rolls towards or away from the camera's rest position.

    Parameters
    ----------
    n_frames : int, default 60
        Number of frames F (>= 2).
    n_points : int, default 10000
        Number of points P (>= 4), the first P of a grid over the sheet.
    camera : {"osc", "turn"}, default "osc"
        Oscillating camera or slow turntable (see :func:`make_sequence`).
    seed : int, default 0
        Seed of the roll's turn, extent, end and sense, the camera phase and the image
        translations.

    Returns
    -------
    sequence : Sequence
    """
    _check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = _streams(seed)
    length, width = 2.0, 2.0 / 1.4
    u, v, faces = _parameter_grid(n_points, aspect=1.4)

    final_turn = np.radians(deformation_rng.uniform(430.0, 540.0))
    final_start = deformation_rng.uniform(0.25, 0.35)
    sense = deformation_rng.choice([-1.0, 1.0])
    flip = deformation_rng.random() < 0.5

    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    progress = times**2 * (3.0 - 2.0 * times)
    s = np.linspace(0.0, length, 2049)
    roll_start = length * (0.9 - (0.9 - final_start) * progress)
    inside = (s - roll_start) / (length - roll_start)
    profile = _sigmoid((s - roll_start) / (0.03 * length)) * (1.0 + 1.5 * np.clip(inside, 0, 1))
    profile /= _cumulative_trapezoid(profile, s[1] - s[0])[:, -1:]
    curvature = sense * final_turn * progress * profile

    arc = 1.0 - u if flip else u
    curve = _bend_sheet(curvature, s[1] - s[0], arc)
    shapes = np.empty((n_frames, n_points, 3))
    shapes[:, :, 0] = curve[..., 0]
    shapes[:, :, 2] = curve[..., 1]
    shapes[:, :, 1] = v * width

    rotations = _hard_camera(n_frames, camera, camera_rng)
    colors = _ramp_colors(u, low=(240, 235, 215), high=(200, 90, 60))
    return _finish(f"roll-{camera}", shapes, rotations, translation_rng, length, faces, colors)


def bumps_sequence(
    n_frames: int = 60,
    n_points: int = 10_000,
    camera: CameraMotion = "osc",
    seed: int = 0,
) -> Sequence:
    """A sheet (1.4 x 1.4) with a 4 x 4 grid of Gaussian bumps that grow and shrink out of phase.

    Bump k sits near the centre of its grid cell (jittered by up to 15 % of the spacing
    0.35), has a width (standard deviation) of 0.38-0.46 of the spacing and a height
    ``h_k(t) = A_k sin(2 pi c_k t + phi_k)`` with ``A_k`` 0.24-0.30 (17-21 % of the side),
    ``c_k`` 1-2 cycles per sequence and phases that alternate by half a cycle between
    neighbouring cells (a checkerboard) plus a random offset of up to a quarter cycle: while
    one bump rises, its neighbours sink into dents.

    Parameters
    ----------
    n_frames : int, default 60
        Number of frames F (>= 2).
    n_points : int, default 10000
        Number of points P (>= 4), the first P of a grid over the sheet.
    camera : {"osc", "turn"}, default "osc"
        Oscillating camera or slow turntable (see :func:`make_sequence`).
    seed : int, default 0
        Seed of the bump positions, widths, heights, frequencies, phases, the camera phase
        and the image translations.

    Returns
    -------
    sequence : Sequence
    """
    _check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = _streams(seed)
    side, n_cells = 1.4, 4
    spacing = side / n_cells
    u, v, faces = _parameter_grid(n_points, aspect=1.0)
    x, y = u * side, v * side

    rows, cols = np.divmod(np.arange(n_cells**2), n_cells)
    centres_x = (cols + 0.5 + deformation_rng.uniform(-0.15, 0.15, n_cells**2)) * spacing
    centres_y = (rows + 0.5 + deformation_rng.uniform(-0.15, 0.15, n_cells**2)) * spacing
    widths = deformation_rng.uniform(0.38, 0.46, n_cells**2) * spacing
    heights = deformation_rng.uniform(0.24, 0.30, n_cells**2)
    cycles = deformation_rng.uniform(1.0, 2.0, n_cells**2)
    phases = np.pi * ((rows + cols) % 2) + deformation_rng.uniform(
        -0.5 * np.pi, 0.5 * np.pi, n_cells**2
    )

    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    amplitude = heights * np.sin(2.0 * np.pi * cycles * times + phases)  # (F, K)
    bump_fields = np.stack(
        [
            _gaussian(x, y, cx, cy, w, w)
            for cx, cy, w in zip(centres_x, centres_y, widths, strict=True)
        ]
    )  # (K, P)
    shapes = np.zeros((n_frames, n_points, 3))
    shapes[:, :, 0] = x
    shapes[:, :, 1] = y
    shapes[:, :, 2] = amplitude @ bump_fields

    rotations = _hard_camera(n_frames, camera, camera_rng)
    colors = _ramp_colors(bump_fields.sum(axis=0), low=(60, 120, 60), high=(230, 220, 140))
    return _finish(f"bumps-{camera}", shapes, rotations, translation_rng, side, faces, colors)


_HARD_GENERATORS = {"flag": flag_sequence, "roll": roll_sequence, "bumps": bumps_sequence}

#: The hard sequences, ``<deformation>-<camera>``: every deformation under both cameras.
HARD_SEQUENCE_NAMES: tuple[str, ...] = tuple(
    f"{deformation}-{camera}" for deformation in _HARD_GENERATORS for camera in CAMERA_MOTIONS
)

# --- registry and noise --------------------------------------------------------------------


def add_noise(W: np.ndarray, noise: float, seed: int = 0) -> np.ndarray:
    """Add Gaussian noise of standard deviation ``noise * max|W|`` (the paper's protocol).

    Parameters
    ----------
    W : ndarray of shape (2F, P), float64
        Image tracks.
    noise : float
        Relative level ``lambda_g`` (the paper uses 0.01 to 0.055); 0 returns a copy.
    seed : int, default 0
        Seed of the noise.

    Returns
    -------
    noisy : ndarray of shape (2F, P), float64
        A new array; ``W`` is not modified.
    """
    W = np.asarray(W, dtype=np.float64)
    if not np.isfinite(noise) or noise < 0:
        raise ValueError(f"noise must be a finite number >= 0, got {noise!r}")
    if noise == 0:
        return W.copy()
    scale = noise * np.max(np.abs(W))
    return W + np.random.default_rng(seed).normal(scale=scale, size=W.shape)


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
        sequence = _HARD_GENERATORS[deformation](
            **{k: v for k, v in sizes.items() if v is not None},
            camera=camera,  # type: ignore[arg-type]
            seed=seed,
        )
    else:
        raise ValueError(
            f"name must be one of {SEQUENCE_NAMES + HARD_SEQUENCE_NAMES}, got {name!r}"
        )
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


def occlusion_mask(
    sequence: Sequence,
    *,
    band: float = 0.2,
    lost: float = 0.1,
    dropout: float = 0.02,
    seed: int = 0,
) -> np.ndarray:
    """Visibility of a sequence's points under a sweeping occluder, lost tracks and dropout.

    * An occluder band covering ``band`` of the image width (of the tracks' x range) sweeps
      once across the object over the sequence, from a random side; points inside it are
      hidden.
    * ``lost`` of the tracks end at a random frame (uniform over the sequence) and stay lost.
    * ``dropout`` of the remaining entries are hidden at random.
    Every point stays visible in at least two frames and every frame sees at least three
    points (the solver's minimum-observation rules): entries are restored where needed.

    Parameters
    ----------
    sequence : Sequence
    band, lost, dropout : float
        Fractions in [0, 1).
    seed : int

    Returns
    -------
    ndarray of shape (F, P), bool
        True where the point is observed.
    """
    rng = np.random.default_rng(seed)
    n_frames, n_points = sequence.n_frames, sequence.n_points
    x = sequence.W.reshape(n_frames, 2, n_points)[:, 0]
    x = x - x.mean(axis=1, keepdims=True)
    low, high = float(x.min()), float(x.max())
    width = band * (high - low)
    # The band's left edge goes from just outside one side to just outside the other.
    edges = np.linspace(low - width, high, n_frames)
    if rng.random() < 0.5:
        edges = edges[::-1]
    visible = ~((x >= edges[:, None]) & (x < edges[:, None] + width))
    ending = rng.choice(n_points, int(round(lost * n_points)), replace=False)
    last = rng.integers(0, n_frames, size=ending.size)
    frames = np.arange(n_frames)[:, None]
    visible[:, ending] &= frames <= last[None, :]
    visible &= rng.random(visible.shape) >= dropout
    # Minimum observations: two frames per point (the first two), three points per frame.
    for j in np.flatnonzero(visible.sum(axis=0) < 2):
        visible[:2, j] = True
    for f in np.flatnonzero(visible.sum(axis=1) < 3):
        visible[f, rng.choice(n_points, 3, replace=False)] = True
    return visible
