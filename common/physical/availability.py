"""Whether this machine can run the physical world: MuJoCo installed and an off-screen
OpenGL context (EGL by default) that renders.

MuJoCo picks its OpenGL back-end from ``MUJOCO_GL`` when it is imported;
:func:`use_egl` sets EGL (off-screen, no display) unless the user chose another.
"""

from __future__ import annotations

import functools
import os

__all__ = ["DEBIAN_PACKAGES", "use_egl", "why_unavailable"]


def use_egl() -> None:
    """Render off-screen through EGL unless ``MUJOCO_GL`` says otherwise (call before
    MuJoCo is imported)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    if os.environ["MUJOCO_GL"] == "egl":
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


@functools.cache
def why_unavailable() -> str | None:
    """None when the physical world can render here, else one line saying why and what
    to install."""
    use_egl()
    try:
        import mujoco
    except ModuleNotFoundError as exc:
        return f"MuJoCo is not installed ({exc}): pip install mujoco"
    except Exception as exc:  # its OpenGL back-end failed to load (no EGL library)
        return _cannot_render(exc)
    try:
        model = mujoco.MjModel.from_xml_string(
            "<mujoco><worldbody><geom type='box' size='.1 .1 .1'/></worldbody></mujoco>"
        )
        with mujoco.Renderer(model, 8, 8) as renderer:
            renderer.update_scene(mujoco.MjData(model))
            renderer.render()
    except Exception as exc:
        return _cannot_render(exc)
    return None


#: Debian's packages of off-screen OpenGL: the EGL loader and Mesa's EGL, its software
#: renderer, and the OpenGL library PyOpenGL loads beside EGL.
DEBIAN_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "libopengl0")


def _cannot_render(exc: Exception) -> str:
    gl = os.environ.get("MUJOCO_GL", "")
    text = str(exc).strip()
    first = f"{type(exc).__name__}: {text.splitlines()[0]}" if text else type(exc).__name__
    return (
        f"MuJoCo cannot render off-screen with MUJOCO_GL={gl} ({first}); install EGL and "
        f"Mesa (Debian: apt-get install {' '.join(DEBIAN_PACKAGES)})"
    )
