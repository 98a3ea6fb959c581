"""
MuJoCo's warnings sent to :mod:`logging`: without a callback of the program's, MuJoCo appends them to
``MUJOCO_LOG.TXT`` in whatever folder the user ran the command from.
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
    Install the callback if MuJoCo is loaded in this process and none is set yet (cheap and idempotent).

    :return: whether MuJoCo's warnings now go to :mod:`logging`.
    """
    mujoco = sys.modules.get("mujoco")
    if mujoco is None or not hasattr(mujoco, "set_mju_user_warning"):
        return False
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_log_warning)
    return True
