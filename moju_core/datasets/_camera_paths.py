"""Camera paths of the generators, as full rotations (F, 3, 3)."""

from __future__ import annotations

from typing import Literal

import numpy as np

RotationFrequency = Literal["low", "high"]


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
SHEET_CAMERA_RANGE_DEG = 60.0


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


def axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
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


def camera_rotations(
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
        axis_rotations(2, np.radians(roll))
        @ axis_rotations(0, np.radians(pitch))
        @ axis_rotations(1, np.radians(yaw))
    )


def swinging_camera(
    n_frames: int,
    motion: CameraMotion,
    rng: np.random.Generator,
    *,
    swing: tuple[float, float, float, float],
    circle: tuple[float, float, float],
    spin_axis: int,
) -> np.ndarray:
    """An oscillating or circling camera path, full rotations (F, 3, 3).

    ``"osc"``: ``R_f = Rx(pitch_f) Ry(yaw_f)`` with ``swing = (yaw amplitude, yaw period,
    pitch amplitude, pitch period)`` (degrees, frames), random phases. ``"turn"``:
    ``R_f = Rx(tilt_f) R_axis(spin_f)`` about ``spin_axis`` with ``circle = (degrees per
    frame, tilt, tilt wobble over the sequence)``, a random start and sense.
    """
    if motion not in CAMERA_MOTIONS:
        raise ValueError(f"camera must be one of {CAMERA_MOTIONS}, got {motion!r}")
    frames = np.arange(n_frames, dtype=np.float64)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
    if motion == "osc":
        yaw_deg, yaw_period, pitch_deg, pitch_period = swing
        yaw = yaw_deg * np.sin(2.0 * np.pi * frames / yaw_period + phases[0])
        pitch = pitch_deg * np.sin(2.0 * np.pi * frames / pitch_period + phases[1])
        return axis_rotations(0, np.radians(pitch)) @ axis_rotations(1, np.radians(yaw))
    rate, tilt_deg, wobble_deg = circle
    sense = rng.choice([-1.0, 1.0])
    spin = np.degrees(phases[0]) + sense * rate * frames
    tilt = tilt_deg + wobble_deg * np.sin(2.0 * np.pi * frames / max(n_frames - 1, 1) + phases[1])
    return axis_rotations(0, np.radians(tilt)) @ axis_rotations(spin_axis, np.radians(spin))


def hard_camera(n_frames: int, motion: CameraMotion, rng: np.random.Generator) -> np.ndarray:
    """Camera path of the hard sequences, full rotations (F, 3, 3); see the constants above.

    ``"osc"``: ``R_f = Rx(pitch_f) Ry(yaw_f)``; ``"turn"``: ``R_f = Rx(tilt_f) Rz(spin_f)``
    (z is the sheets' rest normal, towards the camera at zero rotation).
    """
    return swinging_camera(
        n_frames,
        motion,
        rng,
        swing=(_OSC_YAW_DEG, _OSC_PERIOD_FRAMES, _OSC_PITCH_DEG, _OSC_PITCH_PERIOD_FRAMES),
        circle=(_TURN_RATE_DEG, _TURN_TILT_DEG, _TURN_WOBBLE_DEG),
        spin_axis=2,
    )
