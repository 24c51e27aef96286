"""The video tests need OpenCV (the ``video`` extra): skipped where it is not installed."""

from importlib.util import find_spec

collect_ignore_glob = [] if find_spec("cv2") else ["test_*.py"]
