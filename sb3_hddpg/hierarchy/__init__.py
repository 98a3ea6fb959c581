"""The hierarchy core: worker selection, frozen workers, the manager's env wrapper and :class:`Hierarchy`."""

from sb3_hddpg.hierarchy.bundle import BundleError
from sb3_hddpg.hierarchy.hierarchy import Hierarchy, SelectionConfig
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper

__all__ = ["BundleError", "Hierarchy", "SelectionConfig", "WorkerSelectionWrapper"]
