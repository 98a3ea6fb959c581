"""
The packages of the ``bench`` extra the library uses in a few places, each imported only when used.

``pip install sb3-hddpg`` gives the library without them; where one is missing, what needs it stops with one
line naming the extra (:class:`MissingExtraError`), or, for TensorBoard's logs, training goes on without them.
"""

from __future__ import annotations

import importlib
import importlib.util
import warnings
from types import ModuleType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stable_baselines3.common.logger import Logger

#: The extra that holds the harness's packages and these.
EXTRA = "bench"
#: How to install it, as error lines say it.
INSTALL_EXTRA = f'pip install "sb3-hddpg[{EXTRA}]"'


class MissingExtraError(ModuleNotFoundError):
    """A package of the ``bench`` extra is needed and not installed: one line naming it and the extra."""


def require(module: str, purpose: str) -> ModuleType:
    """
    Import ``module``, a package of the ``bench`` extra.

    :param module: its import name (``scipy.optimize``).
    :param purpose: what needs it, for the error line.
    :raises MissingExtraError: it is not installed.
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as error:
        raise MissingExtraError(
            f"{purpose} needs {module.split('.')[0]}, which is not installed: {INSTALL_EXTRA}",
            name=error.name,
        ) from error


class LazyModule:
    """A module of the ``bench`` extra imported at its first attribute (through :func:`require`)."""

    def __init__(self, module: str, purpose: str) -> None:
        self._module = module
        self._purpose = purpose

    def __getattr__(self, name: str) -> Any:
        return getattr(require(self._module, self._purpose), name)


#: Pillow's image and drawing modules, for frames drawn by the library (the snake's renderer, rollout's PNG).
Image: Any = LazyModule("PIL.Image", "drawing a frame")
ImageDraw: Any = LazyModule("PIL.ImageDraw", "drawing a frame")


def linprog(*args: Any, **kwargs: Any) -> Any:
    """SciPy's ``scipy.optimize.linprog`` (the linear programs of ``grow``'s linear support)."""
    return require("scipy.optimize", "grow's linear support").linprog(*args, **kwargs)


def configure(folder: str | None, formats: list[str]) -> Logger:
    """
    SB3's ``configure``, without the ``tensorboard`` format when TensorBoard is not installed: a training run
    of the library never fails for want of its logs (a warning says how to get them).
    """
    from stable_baselines3.common.logger import configure as sb3_configure  # SB3 only when training

    if "tensorboard" in formats and importlib.util.find_spec("tensorboard") is None:
        warnings.warn(f"TensorBoard is not installed, so no TensorBoard logs: {INSTALL_EXTRA}", stacklevel=2)
        formats = [f for f in formats if f != "tensorboard"]
    return sb3_configure(folder, formats)
