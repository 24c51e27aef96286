"""The video front end: from footage to tracks, and rendered footage to test it on.

* :mod:`~moju_core.footage.video` - decoding a video's frames within size limits;
* :mod:`~moju_core.footage.tracking` - dense point tracks by optical flow, with forward,
  backward and keyframe checks, written as W (2F, P) in pixels with NaN where lost;
* :mod:`~moju_core.footage.render` - rendering a synthetic textured surface into a video
  with known ground truth.

OpenCV (the ``video`` extra) is imported only where frames are decoded or tracked.
"""
