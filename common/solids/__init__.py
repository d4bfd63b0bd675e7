"""Solid objects seen by one camera: upright prisms standing on the floor (cylinders,
boxes, regular prisms), their silhouettes carried onto the floor through the camera's
centre (``silhouette``), their shapes (``shapes``), the fit of a blob's sub-pixel
outline that measures where they stand and how tall they are (``fit``), and each frame's
footprint from a fitted shape (``footprint``).
May import: ``config``, ``camera``, ``vision``.
"""
