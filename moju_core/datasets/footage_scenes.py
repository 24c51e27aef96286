"""Isometrically bending sheets in a static perspective camera's frame, like real footage.

A scene is a sheet of paper or cloth (long side 0.2-0.3 m, aspect 1.4) that bends
isometrically while it turns a little and moves towards or away from a static camera, in the
camera's frame (metres; x right, y down, z forward, the convention of
:mod:`moju_core.cameras.intrinsics`):

* **deformation**: a developable bend, exactly isometric: the sheet's cross-section along a
  bending direction (at up to 25 degrees to its long side) is a plane curve whose curvature
  profile changes over time, integrated by :func:`moju_core.datasets.surfaces.bend_sheet`;
  the generators (straight lines across the bend) keep their length. Three kinds:

  - ``curl``: the far end rolls up (like the ``paper`` sequence's roll), its total turn
    growing from 20-60 to 150-220 degrees while the roll's start moves inwards;
  - ``crease``: a fold across the sheet at 35-65 % of its length, rounded over a bump of
    curvature 6-12 mm wide (standard deviation), folding between 10-40 and 90-140 degrees,
    with a gentle global bend;
  - ``cloth``: three or four soft folds (bumps 10-25 mm wide) at random places, each
    swinging between -70 and +70 degrees with its own period and phase and drifting by up to
    2 cm along the sheet;

* **pose**: the sheet starts 2-5 of its lengths in front of the camera, tilted by up to 30
  degrees about x and 20 about y, turns by 5-30 degrees in total about a mostly vertical axis,
  and its depth changes by 8-20 % (monotonically or out and back), with a lateral drift of up
  to 10 % of its length.

Everything is drawn from ``numpy.random.default_rng([seed, kind])``: one seed and kind give
one scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from moju_core.datasets.surfaces import bend_sheet, cumulative_trapezoid, parameter_grid, sigmoid

__all__ = ["FOOTAGE_KINDS", "FootageScene", "footage_scene"]

#: The deformation kinds of :func:`footage_scene`.
FOOTAGE_KINDS: tuple[str, ...] = ("curl", "crease", "cloth")

_ASPECT = 1.4
# Arc-length samples of the bending curve (bend_sheet's chord error is far below a micron).
_CURVE_SAMPLES = 2049


@dataclass(frozen=True, eq=False)
class FootageScene:
    """A bending sheet in a static camera's frame.

    Attributes
    ----------
    kind : str
        One of :data:`FOOTAGE_KINDS`.
    seed : int
        The seed it was drawn with.
    shapes : ndarray of shape (F, V, 3), float64
        Vertices in the camera frame, metres (x right, y down, z > 0 forward).
    rest : ndarray of shape (V, 3), float64
        The flat sheet (z = 0), metres: the lengths every frame keeps.
    uv : ndarray of shape (V, 2), float64
        Parameter coordinates in [0, 1] (u along the long side), for the texture.
    faces : ndarray of shape (M, 3), int64
        Triangles; their front (counter-clockwise in the image) faces the camera at rest.
    length : float
        Long side of the sheet, metres.
    rotations : ndarray of shape (F, 3, 3), float64
        The sheet's rigid pose (camera from sheet) in every frame.
    centres : ndarray of shape (F, 3), float64
        Where the pose puts the sheet's centroid, metres.
    """

    kind: str
    seed: int
    shapes: np.ndarray
    rest: np.ndarray
    uv: np.ndarray
    faces: np.ndarray
    length: float
    rotations: np.ndarray
    centres: np.ndarray

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.shapes.shape[0])

    @property
    def turn_deg(self) -> float:
        """Angle between the first and the last frame's pose, degrees."""
        relative = self.rotations[-1] @ self.rotations[0].T
        return float(np.degrees(Rotation.from_matrix(relative).magnitude()))

    @property
    def depth_change(self) -> float:
        """Largest relative change of the centroid's depth from the first frame's."""
        return float(np.max(np.abs(self.centres[:, 2] / self.centres[0, 2] - 1.0)))

    @property
    def distance_in_lengths(self) -> float:
        """The first frame's centroid depth in sheet lengths."""
        return float(self.centres[0, 2] / self.length)


def _smoothstep(times: np.ndarray) -> np.ndarray:
    return times**2 * (3.0 - 2.0 * times)


def _bump(s: np.ndarray, centre: np.ndarray, width: float) -> np.ndarray:
    """Unit-area Gaussian bumps (F, K) over arc length ``s`` (K,) at ``centre`` (F,)."""
    offset = (s[None, :] - centre[:, None]) / width
    return np.exp(-0.5 * offset**2) / (width * np.sqrt(2.0 * np.pi))


def _curl(rng: np.random.Generator, s: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Curvature (F, K) of an end rolling up: total turn 20-60 -> 150-220 degrees."""
    start_turn, end_turn = np.radians(rng.uniform(20, 60)), np.radians(rng.uniform(150, 220))
    progress = _smoothstep(times)
    turn = start_turn + (end_turn - start_turn) * progress
    total = s[-1]
    roll_start = total * (rng.uniform(0.75, 0.85) - rng.uniform(0.15, 0.25) * progress)
    profile = sigmoid((s[None, :] - roll_start[:, None]) / (0.03 * total))
    profile /= cumulative_trapezoid(profile, s[1] - s[0])[:, -1:]
    return turn[:, None] * profile


def _crease(rng: np.random.Generator, s: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Curvature (F, K) of a rounded fold plus a gentle global bend."""
    total = s[-1]
    low, high = np.radians(rng.uniform(10, 40)), np.radians(rng.uniform(90, 140))
    if rng.random() < 0.5:
        progress = _smoothstep(times)  # folds once
    else:
        progress = np.sin(np.pi * times)  # folds and opens again
    angle = (low + (high - low) * progress) * rng.choice([-1.0, 1.0])
    centre = np.full(times.size, rng.uniform(0.35, 0.65) * total)
    crease = angle[:, None] * _bump(s, centre, rng.uniform(0.006, 0.012))
    global_bend = np.radians(rng.uniform(-15, 15)) * np.sin(np.pi * times + rng.uniform(0, 1))
    return crease + global_bend[:, None] / total


def _cloth(rng: np.random.Generator, s: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Curvature (F, K) of three or four soft folds swinging and drifting."""
    total = s[-1]
    curvature = np.zeros((times.size, s.size))
    n_folds = int(rng.integers(3, 5))
    for centre in np.sort(rng.uniform(0.15, 0.85, size=n_folds)) * total:
        amplitude = np.radians(rng.uniform(25, 70))
        cycles, phase = rng.uniform(0.4, 1.0), rng.uniform(0, 2 * np.pi)
        angle = amplitude * np.sin(2 * np.pi * cycles * times + phase)
        drift = centre + rng.uniform(-0.02, 0.02) * times
        curvature += angle[:, None] * _bump(s, drift, rng.uniform(0.010, 0.025))
    return curvature


_PROFILES = {"curl": _curl, "crease": _crease, "cloth": _cloth}


def _bent_sheet(
    rng: np.random.Generator, kind: str, flat: np.ndarray, times: np.ndarray
) -> np.ndarray:
    """Isometric bends (F, V, 3) of the flat sheet ``flat`` (V, 2), in the sheet's frame.

    The bending direction is at ``phi`` (up to 25 degrees) to the long side: arc length runs
    along it, the generators across it; the curve of :func:`bend_sheet` maps arc length to
    (in-plane, out-of-plane) coordinates.
    """
    phi = np.radians(rng.uniform(-25, 25))
    along = np.array([np.cos(phi), np.sin(phi)])
    across = np.array([-np.sin(phi), np.cos(phi)])
    arc, generator = flat @ along, flat @ across
    s = np.linspace(0.0, np.ptp(arc), _CURVE_SAMPLES)
    curvature = _PROFILES[kind](rng, s, times)
    curve = bend_sheet(curvature, s[1] - s[0], (arc - arc.min()) / np.ptp(arc))
    in_plane = curve[..., 0:1] * along + generator[None, :, None] * across
    return np.concatenate([in_plane, curve[..., 1:2]], axis=-1)


def _poses(
    rng: np.random.Generator, times: np.ndarray, length: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (F, 3, 3) camera-from-sheet and centroid positions (F, 3), metres."""
    # diag(1, -1, -1): the sheet's v axis up in the image, its +z side towards the camera.
    facing = np.diag([1.0, -1.0, -1.0])
    tilt = Rotation.from_euler(
        "xy", [rng.uniform(-30, 30), rng.uniform(-20, 20)], degrees=True
    ).as_matrix()
    axis = np.array([0.0, 1.0, 0.0]) + 0.3 * rng.normal(size=3)
    turn = np.radians(rng.uniform(5, 30)) * rng.choice([-1.0, 1.0])
    progress = _smoothstep(times)
    spin = Rotation.from_rotvec(
        (turn * (progress - 0.5))[:, None] * axis / np.linalg.norm(axis)
    ).as_matrix()
    rotations = spin @ tilt @ facing
    distance = rng.uniform(2.0, 5.0) * length
    change = rng.uniform(0.08, 0.2) * rng.choice([-1.0, 1.0])
    path = progress if rng.random() < 0.5 else np.sin(np.pi * times)
    drift = rng.uniform(-0.1, 0.1, size=2) * length
    centres = np.zeros((times.size, 3))
    centres[:, :2] = (path[:, None] - 0.5) * drift
    centres[:, 2] = distance * (1.0 + change * path)
    return rotations, centres


def footage_scene(
    kind: str = "curl", *, n_frames: int = 32, n_points: int = 6000, seed: int = 0
) -> FootageScene:
    """A sheet bending isometrically in front of a static camera (see the module's description).

    Parameters
    ----------
    kind : {"curl", "crease", "cloth"}, default "curl"
        The deformation.
    n_frames : int, default 32
        Number of frames F (>= 2).
    n_points : int, default 6000
        Vertices of the sheet's mesh (a grid of about 1.4 columns per row).
    seed : int, default 0
        Seed of the sheet's size, deformation and pose.

    Returns
    -------
    scene : FootageScene
    """
    if kind not in _PROFILES:
        raise ValueError(f"kind must be one of {FOOTAGE_KINDS}, got {kind!r}")
    if n_frames < 2 or n_points < 16:
        raise ValueError(f"need n_frames >= 2 and n_points >= 16, got {n_frames}, {n_points}")
    rng = np.random.default_rng([seed, FOOTAGE_KINDS.index(kind)])
    length = rng.uniform(0.2, 0.3)
    u, v, faces = parameter_grid(n_points, aspect=_ASPECT)
    flat = np.stack([u * length, v * length / _ASPECT], axis=1)
    times = np.linspace(0.0, 1.0, n_frames)
    local = _bent_sheet(rng, kind, flat, times)
    local -= local.mean(axis=1, keepdims=True)
    rotations, centres = _poses(rng, times, length)
    shapes = np.einsum("fij,fvj->fvi", rotations, local) + centres[:, None, :]
    rest = np.concatenate([flat, np.zeros((flat.shape[0], 1))], axis=1)
    return FootageScene(
        kind=kind, seed=seed, shapes=shapes, rest=rest, uv=np.stack([u, v], axis=1),
        faces=faces, length=float(length), rotations=rotations, centres=centres,
    )  # fmt: skip
