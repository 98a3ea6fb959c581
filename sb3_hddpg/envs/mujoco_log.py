"""
MuJoCo's warnings sent to Python's :mod:`logging` instead of a file in the current folder.

Without a warning callback of the program's, MuJoCo appends every warning (``Nan, Inf or huge value in
QACC``...) to ``MUJOCO_LOG.TXT`` in the process's *current* folder, wherever the user ran the command; a
callback replaces that, in this process (each env subprocess installs its own when it makes its env). MuJoCo
offers exactly this hook (``mujoco.set_mju_user_warning``), so nothing needs to change folders.
"""

from __future__ import annotations

import logging
import sys

logger = logging.getLogger("sb3_hddpg.mujoco")
#: The warnings logged in this process: MuJoCo repeats a model's compile warnings (a deprecated attribute of
#: the env's XML) every time an env is made, which a benchmark does hundreds of times; once says it.
_logged: set[str] = set()


def _log_warning(message: str) -> None:
    text = str(message).strip()
    if text not in _logged:
        _logged.add(text)
        logger.warning("MuJoCo: %s", text)


def route_mujoco_warnings() -> bool:
    """
    Install the callback if MuJoCo is loaded in this process and no callback is set yet (a user's own
    stays). Cheap and idempotent: called after each env is made, when a MuJoCo env has loaded the module.

    :return: whether MuJoCo's warnings now go to :mod:`logging`.
    """
    mujoco = sys.modules.get("mujoco")
    if mujoco is None or not hasattr(mujoco, "set_mju_user_warning"):
        return False
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_log_warning)
    return True
