"""The video front end: from footage to tracks, and rendered footage to test it on.

* :mod:`~moju_core.footage.video` - decoding a video's frames within size limits;
* :mod:`~moju_core.footage.tracking` - dense point tracks by optical flow, with forward,
  backward and keyframe checks, written as W (2F, P) in pixels with NaN where lost;
* :mod:`~moju_core.footage.render` - rendering a synthetic textured surface into a video
  with known ground truth;
* :mod:`~moju_core.footage.perspective_render` - the same through a pinhole camera, for
  shapes in the camera's frame (e.g. :mod:`moju_core.datasets.footage_scenes`).

OpenCV (the ``video`` extra) is imported only where frames are decoded or tracked.
"""
