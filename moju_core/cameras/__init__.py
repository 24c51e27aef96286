"""Camera rotations of orthographic image sequences.

:func:`estimate_cameras` is the entry point: it runs the rotation estimator named by the
solver's ``rotations`` parameter and, for ``"auto"``, chooses between them. The modules:

* :mod:`~moju_core.cameras.projection` - orthographic projection, back-projection and the
  S-update of the ADMM loop on stacks of per-frame rotations;
* :mod:`~moju_core.cameras.rigid` - Tomasi and Kanade's rigid factorisation;
* :mod:`~moju_core.cameras.intersection` - Dai, Li and He's prior-free method (the PSD
  relaxation), refined by the joint fit of corrective triples
  (:mod:`~moju_core.cameras.triples`);
* :mod:`~moju_core.cameras.windowed` - rigid factorisations of short windows of frames,
  chained, and the short-time rigidity that ``"auto"`` compares;
* :mod:`~moju_core.cameras.plane` - rotations of a sheet from the calibration of its dominant
  plane, fitted robustly to groups of tracks (``"plane"``, selectable by name only);
* :mod:`~moju_core.cameras.refinement` - projection onto orthonormal rows and the refinement
  of rotations against given shapes;
* :mod:`~moju_core.cameras.bases` - how many shape bases W supports, and the checks of W;
* :mod:`~moju_core.cameras.symmetric` - symmetric-matrix vectorisation and the PSD cone.

The spectrum of W that several of them read is in :mod:`moju_core.spectrum`. The package
loads the estimators (and SciPy) only when :func:`estimate_cameras` is first asked for, so
that importing :mod:`~moju_core.cameras.projection` stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from moju_core.cameras.estimate import CameraEstimate, estimate_cameras

__all__ = ["CameraEstimate", "estimate_cameras"]


def __getattr__(name: str):
    if name in __all__:
        from moju_core.cameras import estimate

        return getattr(estimate, name)
    raise AttributeError(name)
