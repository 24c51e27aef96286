"""An articulated body with markers, like a motion-capture sequence (:data:`BODY_SEQUENCE_NAMES`).

A stick figure of 17 joints (pelvis, spine, chest, neck, head, shoulders, elbows, wrists,
hips, knees, ankles; about 1.7 units tall) moves every joint by smooth angles; markers ride
rigidly on the 16 bones, as reflective markers on a performer's limbs. Unlike the faces and
sheets, the deformation is piecewise rigid and not of low rank: the shape matrix's spectrum
decays without a gap, and markers of different limbs move independently.
"""

from __future__ import annotations

import numpy as np

from moju_core.datasets._assembly import check_sizes, finish, streams
from moju_core.datasets._camera_paths import (
    CameraMotion,
    axis_rotations,
    swinging_camera,
)
from moju_core.datasets.sequence import Sequence

#: The names :func:`moju_core.datasets.make_sequence` knows for :func:`body_sequence`.
BODY_SEQUENCE_NAMES: tuple[str, ...] = ("body-osc", "body-turn")

#: Joint -> (parent, offset from the parent joint in the parent's frame at rest); y is up.
JOINTS: dict[str, tuple[str | None, tuple[float, float, float]]] = {
    "pelvis": (None, (0.0, 0.0, 0.0)),
    "spine": ("pelvis", (0.0, 0.25, 0.0)),
    "chest": ("spine", (0.0, 0.25, 0.0)),
    "neck": ("chest", (0.0, 0.2, 0.0)),
    "head": ("neck", (0.0, 0.15, 0.0)),
    "left shoulder": ("chest", (0.18, 0.1, 0.0)),
    "left elbow": ("left shoulder", (0.0, -0.28, 0.0)),
    "left wrist": ("left elbow", (0.0, -0.25, 0.0)),
    "right shoulder": ("chest", (-0.18, 0.1, 0.0)),
    "right elbow": ("right shoulder", (0.0, -0.28, 0.0)),
    "right wrist": ("right elbow", (0.0, -0.25, 0.0)),
    "left hip": ("pelvis", (0.1, 0.0, 0.0)),
    "left knee": ("left hip", (0.0, -0.42, 0.0)),
    "left ankle": ("left knee", (0.0, -0.4, 0.0)),
    "right hip": ("pelvis", (-0.1, 0.0, 0.0)),
    "right knee": ("right hip", (0.0, -0.42, 0.0)),
    "right ankle": ("right knee", (0.0, -0.4, 0.0)),
}
#: Amplitude (degrees) of each of the two sinusoids of a joint's flexion (about x); the
#: rotations about y and z have half of it. Wrists and ankles end bones and do not rotate.
FLEXION_DEG: dict[str, float] = {
    "pelvis": 3.75, "spine": 3.75, "chest": 3.75, "neck": 5.0, "head": 2.5,
    "left shoulder": 17.5, "left elbow": 15.0, "right shoulder": 17.5, "right elbow": 15.0,
    "left hip": 10.0, "left knee": 12.5, "right hip": 10.0, "right knee": 12.5,
}  # fmt: skip
#: Periods (frames) of the joint angles' sinusoids, drawn uniformly from this range.
PERIOD_FRAMES = (80.0, 300.0)
#: Standard deviation of a marker's offset from its bone (units), and the part of the bone's
#: length it sits along (from the parent joint).
MARKER_OFFSET = 0.04
MARKER_ALONG = (0.1, 1.0)
#: ``osc``: yaw +-30 degrees with a period of 60 frames, pitch +-10 degrees with a period of
#: 97 frames. ``turn``: the camera circles the performer by 2 degrees per frame (random start
#: and sense), 10 +- 5 degrees above the horizon.
OSC_YAW_DEG, OSC_YAW_PERIOD, OSC_PITCH_DEG, OSC_PITCH_PERIOD = 30.0, 60.0, 10.0, 97.0
TURN_RATE_DEG, TURN_TILT_DEG, TURN_WOBBLE_DEG = 2.0, 10.0, 5.0

_BONES = tuple(name for name, (parent, _) in JOINTS.items() if parent is not None)


def marker_bones(n_points: int) -> np.ndarray:
    """The bone (child joint index into :data:`JOINTS`) each marker rides on, (P,) int64:
    the bones in turn."""
    children = np.array([list(JOINTS).index(bone) for bone in _BONES], dtype=np.int64)
    return children[np.arange(n_points) % len(_BONES)]


def _euler(angles_deg: np.ndarray) -> np.ndarray:
    """``Rx Ry Rz`` of per-frame angles (F, 3) in degrees, (F, 3, 3)."""
    radians = np.radians(angles_deg)
    return (
        axis_rotations(0, radians[:, 0])
        @ axis_rotations(1, radians[:, 1])
        @ axis_rotations(2, radians[:, 2])
    )


def _joint_angles(n_frames: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Each joint's angles (F, 3) in degrees: two sinusoids per axis, random periods/phases."""
    frames = np.arange(n_frames, dtype=np.float64)[:, None]
    angles = {}
    for joint in JOINTS:
        amplitude = FLEXION_DEG.get(joint, 0.0) * np.array([1.0, 0.5, 0.5])
        periods = rng.uniform(*PERIOD_FRAMES, size=(2, 3))
        phases = rng.uniform(0.0, 2.0 * np.pi, size=(2, 3))
        waves = np.sin(2.0 * np.pi * frames[:, None, :] / periods + phases)  # (F, 2, 3)
        angles[joint] = amplitude * waves.sum(axis=1)
    return angles


def _pose(n_frames: int, rng: np.random.Generator) -> tuple[dict, dict]:
    """Forward kinematics: every joint's world rotation (F, 3, 3) and position (F, 3)."""
    angles = _joint_angles(n_frames, rng)
    rotation: dict[str, np.ndarray] = {}
    position: dict[str, np.ndarray] = {}
    for joint, (parent, offset) in JOINTS.items():  # parents come first
        local = _euler(angles[joint])
        if parent is None:
            rotation[joint], position[joint] = local, np.zeros((n_frames, 3))
            continue
        position[joint] = position[parent] + rotation[parent] @ np.asarray(offset)
        rotation[joint] = rotation[parent] @ local
    return rotation, position


def body_sequence(
    n_frames: int = 350,
    n_points: int = 41,
    camera: CameraMotion = "osc",
    seed: int = 0,
) -> Sequence:
    """Markers on an articulated body, seen by an oscillating or circling camera.

    Every joint but the wrists and ankles turns by two sinusoids per axis (periods 80-300
    frames; flexion up to 35 degrees at the shoulders, 30 at the elbows, 25 at the knees, 20
    at the hips, 7.5-10 along the spine and neck; half of that about the other two axes).
    Marker j rides on bone ``marker_bones(P)[j]`` at a random point along it, offset by
    ``MARKER_OFFSET`` (standard deviation) from its axis, and keeps its place on the bone.

    Parameters
    ----------
    n_frames : int, default 350
        Number of frames F (>= 2).
    n_points : int, default 41
        Number of markers P (>= 4), spread over the 16 bones in turn.
    camera : {"osc", "turn"}, default "osc"
        ``osc``: yaw +-30 degrees (period 60 frames) and pitch +-10 degrees (period 97);
        ``turn``: circling the body by 2 degrees per frame, 10 +- 5 degrees above it.
    seed : int, default 0
        The same seed gives the same motion and markers under both cameras.

    Returns
    -------
    Sequence
        ``faces`` is None (markers, no surface); colours by bone.
    """
    check_sizes(n_frames, n_points)
    motion_rng, camera_rng, translation_rng = streams(seed)
    rotation, position = _pose(n_frames, motion_rng)
    bones = marker_bones(n_points)
    names = list(JOINTS)
    along = motion_rng.uniform(*MARKER_ALONG, size=n_points)
    offsets = motion_rng.normal(0.0, MARKER_OFFSET, size=(n_points, 3))
    shapes = np.empty((n_frames, n_points, 3))
    for j, bone in enumerate(bones):
        parent = JOINTS[names[bone]][0]
        local = along[j] * np.asarray(JOINTS[names[bone]][1]) + offsets[j]
        shapes[:, j] = position[parent] + rotation[parent] @ local
    palette = np.array([[200, 80, 60], [60, 140, 200], [90, 170, 90], [220, 180, 60]])
    colors = palette[bones % len(palette)].astype(np.uint8)
    camera_path = swinging_camera(
        n_frames,
        camera,
        camera_rng,
        swing=(OSC_YAW_DEG, OSC_YAW_PERIOD, OSC_PITCH_DEG, OSC_PITCH_PERIOD),
        circle=(TURN_RATE_DEG, TURN_TILT_DEG, TURN_WOBBLE_DEG),
        spin_axis=1,
    )
    return finish(f"body-{camera}", shapes, camera_path, translation_rng, 1.7, None, colors)
