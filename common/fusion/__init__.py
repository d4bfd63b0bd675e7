"""Several cameras over one arena, fused into one world: what cameras saw as columns
(``sightings``), each camera's expected position error on the floor (``accuracy``) and
whether a blob is cut by its image border (``border``), both from tables that a world
frame reads in one pass for all its cameras (``tables``), frames matched by capture time
(``matching``), the same robot or obstacle merged once with accuracy weights
(``merge``), what a late camera should judge (``coverage``) and world identities kept
across hand-overs between cameras (``tracks``).
May import: ``config``, ``camera``.
"""
