"""Calibration: DIPE (``dipe``, eq. 14), the binary GA (``ga``, §4), the calibration
problem and its fitness (``problem``, eqs. 15–16), the constrained GA run and its result
packaged (``solve``), one frame calibrated (``calibrate``) for the paper model and the
pinhole camera (``pinhole``), why a GA found nothing feasible (``infeasible``), the
least-squares polish (``refine``), held-out accuracy (``accuracy``) and quality
(``quality``), the calibration file (``file``) and the versioned store (``store``).
May import: ``config``, ``atomic``, ``camera``, ``vision``.
"""
