"""
Rendering without a display: OpenGL errors of a headless machine reported in one line naming the fix
(``MUJOCO_GL=egl``), and a private runtime folder for the libraries that want one.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator

#: Words in the type or message of an error that only an OpenGL context that could not be made raises
#: (GLFW without a display, OSMesa without its library, MuJoCo's own checks, a bad ``MUJOCO_GL``).
GL_MARKERS = ("GLFW", "glGetError", "OpenGL", "OSMesa", "MUJOCO_GL", "mjr_makeContext", "opengl_context")

#: The fix, named in every such error and in docs/ENVIRONMENTS.md.
HEADLESS_HINT = (
    "on a machine without a display set MUJOCO_GL=egl (e.g. MUJOCO_GL=egl hddpg-cli record ...); "
    "see docs/ENVIRONMENTS.md, 'Rendering without a display'"
)


class HeadlessRenderingError(RuntimeError):
    """The env could not make an OpenGL context to render with (no display): not a problem of any file."""


def as_rendering_error(error: BaseException) -> HeadlessRenderingError | None:
    """
    The one-line rendering error ``error`` (or an error it was raised from) is, if it is an OpenGL context
    that could not be made, else ``None``.

    :param error: any error.
    """
    seen: BaseException | None = error
    for _ in range(8):  # the chain of causes, bounded
        if seen is None:
            return None
        if isinstance(seen, HeadlessRenderingError):
            return seen
        kind = f"{type(seen).__module__}.{type(seen).__name__}"
        text = " ".join(f"{kind}: {seen}".split())
        if any(marker in text for marker in GL_MARKERS):
            return HeadlessRenderingError(f"Cannot render: no OpenGL context ({text[:200]}); {HEADLESS_HINT}")
        seen = seen.__cause__ or seen.__context__
    return None


@contextlib.contextmanager
def rendering_errors() -> Iterator[None]:
    """Inside this block an OpenGL context that could not be made is raised as :class:`HeadlessRenderingError`."""
    try:
        yield
    except Exception as error:
        rendering = as_rendering_error(error)
        if rendering is None or rendering is error:
            raise
        raise rendering from None


def private_runtime_dir() -> str | None:
    """
    Give this process (and its children) a private ``XDG_RUNTIME_DIR`` when it has no usable one: SDL, GLFW
    and Wayland print an alarming "XDG_RUNTIME_DIR is invalid or not set" without one, then render all the
    same. The folder is temporary, its owner's only, and removed at exit; a usable one of the user's is kept.

    :return: the folder made, or ``None`` when the user's own is kept.
    """
    current = os.environ.get("XDG_RUNTIME_DIR")
    if current:
        with contextlib.suppress(OSError):
            info = os.stat(current)
            if stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and not info.st_mode & 0o077:
                return None
    folder = tempfile.mkdtemp(prefix="hddpg-runtime-")  # mode 0700
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    os.environ["XDG_RUNTIME_DIR"] = folder
    return folder
