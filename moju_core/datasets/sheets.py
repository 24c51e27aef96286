"""The ``paper`` and ``cloth`` sequences: a sheet that bends and rolls up, and a waving cloth."""

from __future__ import annotations

import numpy as np

from moju_core.datasets._assembly import sheet_start
from moju_core.datasets._camera_paths import SHEET_CAMERA_RANGE_DEG, camera_rotations
from moju_core.datasets.sequence import Sequence
from moju_core.datasets.surfaces import (
    bend_sheet,
    cumulative_trapezoid,
    ramp_colors,
    sigmoid,
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
    sheet = sheet_start(n_frames, n_points, seed, aspect=1.4)
    length, width = 2.0, 2.0 / 1.4
    u, v, times, rng = sheet.u, sheet.v, sheet.times, sheet.deformation_rng

    final_turn = np.radians(rng.uniform(200.0, 240.0))
    s_bend = rng.uniform(0.25, 0.40)  # half the peak tangent angle, radians

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

    camera = camera_rotations(n_frames, SHEET_CAMERA_RANGE_DEG, "high", sheet.camera_rng)
    colors = ramp_colors(u, low=(235, 235, 225), high=(120, 160, 220))
    return sheet.finish("paper", shapes, camera, length, colors)


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
    length, height = 1.4, 1.0
    sheet = sheet_start(n_frames, n_points, seed, aspect=length / height)
    u, v, times, rng = sheet.u, sheet.v, sheet.times, sheet.deformation_rng
    x, y = u * length, v * height

    directions = np.array([0.0, 1.0, -1.4]) + rng.uniform(-0.3, 0.3, size=3)
    wavelengths = rng.uniform(0.5, 1.0, size=3) * length
    amplitudes = rng.uniform(0.10, 0.16, size=3) * length
    travel = rng.uniform(1.0, 2.0, size=3)  # wavelengths per sequence
    phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
    bend_phase = rng.uniform(0.0, 2.0 * np.pi)

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

    camera = camera_rotations(n_frames, SHEET_CAMERA_RANGE_DEG, "high", sheet.camera_rng)
    colors = ramp_colors(x + 0.5 * y, low=(170, 30, 40), high=(250, 200, 70))
    return sheet.finish("cloth", shapes, camera, length, colors)
