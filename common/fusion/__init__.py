"""Several cameras over one arena, fused into one world: each camera's expected position
error on the floor (``accuracy``), frames matched by capture time (``matching``), the
same robot or obstacle merged once with accuracy weights (``merge``) and world
identities kept across hand-overs between cameras (``tracks``).
May import: ``config``, ``camera``.
"""
