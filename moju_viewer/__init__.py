"""moju_viewer: the result viewer of the web page and of ``moju view``, outside the solver.

* :mod:`moju_viewer.data` turns a reconstruction into the JSON documents the viewer draws
  (the subset of points a browser can show, depth, colours, rounding);
* :mod:`moju_viewer.assets` holds the viewer's script and style sheet (``static/``) and finds
  plotly.js, for the service's page and for the standalone file alike.

It depends on :mod:`moju_core` (to read results) and on nothing of the service.
"""
