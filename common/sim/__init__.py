"""The built-in simulated arena (``arena``): frames rendered through a camera model, with
ground truth for every object; marked robots drive on crossing paths (``paths``) and
carry markers drawn from the vision layer's dictionaries.
May import: ``config``, ``atomic``, ``camera``, ``vision``.
"""
