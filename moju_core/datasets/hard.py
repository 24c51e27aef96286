"""The hard sequences (:data:`HARD_SEQUENCE_NAMES`): large deformations (flag, roll, bumps)
under two camera motions (``osc``, ``turn``).
"""

from __future__ import annotations

import numpy as np

from moju_core.datasets._assembly import sheet_start
from moju_core.datasets._camera_paths import CAMERA_MOTIONS, CameraMotion, hard_camera
from moju_core.datasets.sequence import Sequence
from moju_core.datasets.surfaces import (
    bend_sheet,
    cumulative_trapezoid,
    gaussian,
    ramp_colors,
    sigmoid,
)


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
        Oscillating camera or slow turntable (see :mod:`moju_core.datasets`).
    seed : int, default 0
        Seed of the wave directions, wavelengths, phases, the camera phase and the image
        translations.

    Returns
    -------
    sequence : Sequence
    """
    length, height = 1.4, 1.0
    sheet = sheet_start(n_frames, n_points, seed, aspect=length / height)
    u, v, times, rng = sheet.u, sheet.v, sheet.times, sheet.deformation_rng
    x, y = u * length, v * height

    n_waves = 2
    directions = rng.uniform(-0.5, 0.5, size=n_waves)
    wavelengths = rng.uniform(0.5, 0.85, size=n_waves) * length
    amplitudes = rng.uniform(0.10, 0.12, size=n_waves) * length
    travel = rng.uniform(1.5, 3.0, size=n_waves)  # wavelengths per sequence
    phases = rng.uniform(0.0, 2.0 * np.pi, size=n_waves)

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

    rotations = hard_camera(n_frames, camera, sheet.camera_rng)
    colors = ramp_colors(x - 0.3 * y, low=(30, 60, 170), high=(240, 240, 240))
    return sheet.finish(f"flag-{camera}", shapes, rotations, length, colors)


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
        Oscillating camera or slow turntable (see :mod:`moju_core.datasets`).
    seed : int, default 0
        Seed of the roll's turn, extent, end and sense, the camera phase and the image
        translations.

    Returns
    -------
    sequence : Sequence
    """
    sheet = sheet_start(n_frames, n_points, seed, aspect=1.4)
    length, width = 2.0, 2.0 / 1.4
    u, v, times, rng = sheet.u, sheet.v, sheet.times, sheet.deformation_rng

    final_turn = np.radians(rng.uniform(430.0, 540.0))
    final_start = rng.uniform(0.25, 0.35)
    sense = rng.choice([-1.0, 1.0])
    flip = rng.random() < 0.5

    progress = times**2 * (3.0 - 2.0 * times)
    s = np.linspace(0.0, length, 2049)
    roll_start = length * (0.9 - (0.9 - final_start) * progress)
    inside = (s - roll_start) / (length - roll_start)
    profile = sigmoid((s - roll_start) / (0.03 * length)) * (1.0 + 1.5 * np.clip(inside, 0, 1))
    profile /= cumulative_trapezoid(profile, s[1] - s[0])[:, -1:]
    curvature = sense * final_turn * progress * profile

    arc = 1.0 - u if flip else u
    curve = bend_sheet(curvature, s[1] - s[0], arc)
    shapes = np.empty((n_frames, n_points, 3))
    shapes[:, :, 0] = curve[..., 0]
    shapes[:, :, 2] = curve[..., 1]
    shapes[:, :, 1] = v * width

    rotations = hard_camera(n_frames, camera, sheet.camera_rng)
    colors = ramp_colors(u, low=(240, 235, 215), high=(200, 90, 60))
    return sheet.finish(f"roll-{camera}", shapes, rotations, length, colors)


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
        Oscillating camera or slow turntable (see :mod:`moju_core.datasets`).
    seed : int, default 0
        Seed of the bump positions, widths, heights, frequencies, phases, the camera phase
        and the image translations.

    Returns
    -------
    sequence : Sequence
    """
    sheet = sheet_start(n_frames, n_points, seed, aspect=1.0)
    side, n_cells = 1.4, 4
    spacing = side / n_cells
    u, v, times, rng = sheet.u, sheet.v, sheet.times, sheet.deformation_rng
    x, y = u * side, v * side

    rows, cols = np.divmod(np.arange(n_cells**2), n_cells)
    centres_x = (cols + 0.5 + rng.uniform(-0.15, 0.15, n_cells**2)) * spacing
    centres_y = (rows + 0.5 + rng.uniform(-0.15, 0.15, n_cells**2)) * spacing
    widths = rng.uniform(0.38, 0.46, n_cells**2) * spacing
    heights = rng.uniform(0.24, 0.30, n_cells**2)
    cycles = rng.uniform(1.0, 2.0, n_cells**2)
    phases = np.pi * ((rows + cols) % 2) + rng.uniform(-0.5 * np.pi, 0.5 * np.pi, n_cells**2)

    amplitude = heights * np.sin(2.0 * np.pi * cycles * times + phases)  # (F, K)
    bump_fields = np.stack(
        [
            gaussian(x, y, cx, cy, w, w)
            for cx, cy, w in zip(centres_x, centres_y, widths, strict=True)
        ]
    )  # (K, P)
    shapes = np.zeros((n_frames, n_points, 3))
    shapes[:, :, 0] = x
    shapes[:, :, 1] = y
    shapes[:, :, 2] = amplitude @ bump_fields

    rotations = hard_camera(n_frames, camera, sheet.camera_rng)
    colors = ramp_colors(bump_fields.sum(axis=0), low=(60, 120, 60), high=(230, 220, 140))
    return sheet.finish(f"bumps-{camera}", shapes, rotations, side, colors)


HARD_GENERATORS = {"flag": flag_sequence, "roll": roll_sequence, "bumps": bumps_sequence}

#: The hard sequences, ``<deformation>-<camera>``: every deformation under both cameras.
HARD_SEQUENCE_NAMES: tuple[str, ...] = tuple(
    f"{deformation}-{camera}" for deformation in HARD_GENERATORS for camera in CAMERA_MOTIONS
)
