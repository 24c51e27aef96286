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

``body-osc`` and ``body-turn`` (:data:`BODY_SEQUENCE_NAMES`) are sparse and articulated, like a
motion capture: 41 markers riding on the bones of a 17-joint body that moves every joint
smoothly (periods 80-300 frames), 350 frames, under an oscillating camera (+-30 degrees,
period 60 frames) or a camera circling the body by 2 degrees per frame.

Every sequence is an orthographic projection ``W_f = R_f S_f + t_f`` of the true shapes, with
per-frame image translations ``t_f`` so that translation removal is exercised; lengths are in
"object units" (face width 2, sheet lengths about 2 and 1.4), the image is in the same units.
The noise protocol of the paper (Gaussian noise of standard deviation ``lambda_g * max|W|``)
is :func:`add_noise`. Everything is deterministic given ``seed``.

The package's modules: :mod:`~moju_core.datasets.sequence` (the :class:`Sequence` type),
:mod:`~moju_core.datasets.faces`, :mod:`~moju_core.datasets.sheets` (paper, cloth) and
:mod:`~moju_core.datasets.hard` and :mod:`~moju_core.datasets.body` (the generators),
:mod:`~moju_core.datasets.registry` (:func:`make_sequence` by name),
:mod:`~moju_core.datasets.noise` and :mod:`~moju_core.datasets.occlusion`, and the surface
building blocks they share (:mod:`~moju_core.datasets.surfaces`: point grids with their
meshes, bumps, bending). Import the public names from ``moju_core.datasets``.
"""

from moju_core.datasets._camera_paths import CAMERA_MOTIONS, CameraMotion, RotationFrequency
from moju_core.datasets.body import BODY_SEQUENCE_NAMES, body_sequence
from moju_core.datasets.faces import face_sequence
from moju_core.datasets.hard import (
    HARD_SEQUENCE_NAMES,
    bumps_sequence,
    flag_sequence,
    roll_sequence,
)
from moju_core.datasets.noise import add_noise, perturb_rotations
from moju_core.datasets.occlusion import occlusion_mask
from moju_core.datasets.registry import SEQUENCE_NAMES, make_sequence
from moju_core.datasets.sequence import Sequence
from moju_core.datasets.sheets import cloth_sequence, paper_sequence

__all__ = [
    "BODY_SEQUENCE_NAMES",
    "CAMERA_MOTIONS",
    "HARD_SEQUENCE_NAMES",
    "SEQUENCE_NAMES",
    "CameraMotion",
    "RotationFrequency",
    "Sequence",
    "add_noise",
    "perturb_rotations",
    "body_sequence",
    "bumps_sequence",
    "cloth_sequence",
    "face_sequence",
    "flag_sequence",
    "make_sequence",
    "occlusion_mask",
    "paper_sequence",
    "roll_sequence",
]
