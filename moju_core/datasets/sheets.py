"""The ``paper`` and ``cloth`` sequences: a sheet that bends and rolls up, and a waving cloth."""

from __future__ import annotations

import numpy as np

from moju_core.datasets._assembly import check_sizes, finish, streams
from moju_core.datasets._camera_paths import SHEET_CAMERA_RANGE_DEG, camera_rotations
from moju_core.datasets._surface import (
    bend_sheet,
    cumulative_trapezoid,
    parameter_grid,
    ramp_colors,
    sigmoid,
)
from moju_core.datasets.sequence import Sequence


def paper_sequence(n_frames: int = 60, n_points: int = 10_000, seed: int = 0) -> Sequence:
    """A sheet of paper (2 x 1.43, aspect 1.4) that bends and then rolls up, isometrically.

    The sheet is a developable surface with straight generators along its short side: its
    cross-section is a plane curve with arc length ``s`` along the long side and curvature
    ``kappa(s, t)``; integrating ``theta = int kappa ds``, ``x = int cos(theta) ds``,
    ``z = int sin(theta) ds`` on a fine grid gives a curve of exactly the sheet's length, so
    the paper never stretches. The curvature mixes a transient S-shaped bend (peaking in
    mid-sequence) with a roll at the far end whose total turn grows smoothly from 0 to
    200-240 degrees while its start moves from 85 % to 40 % of the length. The camera yaws
    +-60 degrees (three cycles) with some pitch and roll (see ``SHEET_CAMERA_RANGE_DEG``).

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
    check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = streams(seed)
    length, width = 2.0, 2.0 / 1.4
    u, v, faces = parameter_grid(n_points, aspect=1.4)

    final_turn = np.radians(deformation_rng.uniform(200.0, 240.0))
    s_bend = deformation_rng.uniform(0.25, 0.40)  # half the peak tangent angle, radians

    times = np.linspace(0.0, 1.0, n_frames)[:, None]
    progress = times**2 * (3.0 - 2.0 * times)  # smoothstep: rolling starts and ends gently
    # 2049 samples keep the polyline's chord error far below anything a test can see.
    s = np.linspace(0.0, length, 2049)
    step = s[1] - s[0]
    roll_start = length * (0.85 - 0.45 * progress)
    roll_profile = sigmoid((s - roll_start) / (0.04 * length))
    roll_profile /= cumulative_trapezoid(roll_profile, step)[:, -1:]
    curvature = final_turn * progress * roll_profile
    curvature += (
        s_bend * np.sin(np.pi * times) * (2.0 * np.pi / length) * np.sin(2.0 * np.pi * s / length)
    )
    curve = bend_sheet(curvature, step, u)
    shapes = np.empty((n_frames, n_points, 3))
    shapes[:, :, 0] = curve[..., 0]
    shapes[:, :, 2] = curve[..., 1]
    shapes[:, :, 1] = v * width

    camera = camera_rotations(n_frames, SHEET_CAMERA_RANGE_DEG, "high", camera_rng)
    colors = ramp_colors(u, low=(235, 235, 225), high=(120, 160, 220))
    return finish("paper", shapes, camera, translation_rng, length, faces, colors)


def cloth_sequence(n_frames: int = 60, n_points: int = 10_000, seed: int = 0) -> Sequence:
    """A waving cloth (1.4 x 1): travelling waves plus a slowly changing global bend.

    Three sinusoidal waves with different directions, wavelengths of 0.7-1.4 (half to all of
    the cloth's length), amplitudes of 0.14-0.22 (10-16 % of the length) travel across the
    cloth, each moving 1-2 wavelengths over the sequence. Like a flag on a pole their
    amplitude grows from the left edge (25 %) to the right edge (100 %), and they carry a
    small in-plane component (water-wave style). A global bend along the long side changes
    slowly. The camera yaws +-60 degrees (three cycles) with some pitch and roll (see
    ``SHEET_CAMERA_RANGE_DEG``).

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
    check_sizes(n_frames, n_points)
    deformation_rng, camera_rng, translation_rng = streams(seed)
    length, height = 1.4, 1.0
    u, v, faces = parameter_grid(n_points, aspect=length / height)
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

    camera = camera_rotations(n_frames, SHEET_CAMERA_RANGE_DEG, "high", camera_rng)
    colors = ramp_colors(x + 0.5 * y, low=(170, 30, 40), high=(250, 200, 70))
    return finish("cloth", shapes, camera, translation_rng, length, faces, colors)
