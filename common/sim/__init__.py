"""The built-in simulated arena (``arena``): frames rendered through a camera model, with
ground truth for every object.
May import: ``config``, ``atomic``, ``camera``.
"""
