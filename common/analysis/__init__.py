"""Offline analysis: the paper's parametric study (``study``), GA vs least squares
(``compare``), accuracy against ground truth (``evaluation``) and plots (``plots``).
May import: anything in ``common``.
"""
