"""The physical world: solid obstacles and robots of every height on a floor under
ceiling lights, simulated and rendered by MuJoCo (``mujoco``, off-screen through EGL)
through a calibrated camera, with ground truth read from the physics state. What
stands where (``scene``), the MuJoCo model (``model``), the camera as MuJoCo renders it
(``camera``), the world in time (``world``), whether this machine can render
(``availability``); a printed calibration board held up or on the floor (``boards``);
the floor marks measured and calibrated on (``marks``), the data set ``ovis simulate
--world physical`` writes (``dataset``), the simulated camera grid over it (``grid``).
May import: ``config``, ``atomic``, ``camera``, ``vision``, ``sim``, ``calibration``.
"""

from ovis.common.physical.availability import use_egl

use_egl()  # before anything imports mujoco: off-screen rendering unless MUJOCO_GL says otherwise
