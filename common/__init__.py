"""ovis's pure logic: no Zenoh, no processes, no files but those a caller names.

Subpackages by concern, each importing only those below it (``tests/test_layout.py``
enforces it; ``LAYERS`` there is the rule written down):

- ``config``, ``atomic`` (top-level modules): configuration Structs, presets, atomic writes.
- ``camera``: camera models, world ⇄ pixel (paper eqs. 2–10), export to OpenCV/ROS.
- ``vision``: frame → binary image → labeled blobs with shape (paper §3, eq. 13).
- ``world``: blobs → robot, obstacles, identities, planner inputs (paper §5.2).
- ``calibration``: DIPE (eq. 14), the GA and its problems (eqs. 15–16), polish, accuracy,
  the calibration file and store.
- ``sim``: the simulated arena and its ground truth.
- ``capture``: frame sources (simulator, folder, video, camera).
- ``messages`` (top-level module): what travels on the bus.
- ``analysis``: study, comparison, evaluation against truth, plots.

Nothing in ``common`` imports ``ovis.services``.
"""
