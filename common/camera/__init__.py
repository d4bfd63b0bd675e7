"""Camera models: world point (cm) ⇄ pixel (row, col).

The paper's model (``paper_model``, eqs. 2–6 and 9–10) with its radial distortion
(``distortion``, eqs. 7–8), the general pinhole + Brown–Conrady camera (``pinhole``), the
one interface the rest of ovis uses (``projection``), and export to OpenCV/ROS (``export``).
May import: ``config``, ``atomic``.
"""
