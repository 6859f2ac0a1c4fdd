"""What the pipeline tells a view, and the view that does nothing when nobody watches."""

from __future__ import annotations

from typing import Protocol

from vmp.types import FloatArray

__all__ = ["NullView", "View"]


class View(Protocol):
    """Receives plain arrays and values as the map is built (``viz`` implements it)."""

    def scan(self, index: int, stamp: float, pose: FloatArray, odom: FloatArray,
             true_pose: FloatArray | None) -> None: ...

    def milestone(self, milestone_id: int, pose: FloatArray) -> None: ...

    def match(self, milestone_id: int, milestone_pose: FloatArray, robot_pose: FloatArray,
              accepted: bool, reason: str) -> None: ...

    def anchors_moved(self, ids: FloatArray, poses: FloatArray) -> None: ...

    def close(self) -> None: ...


class NullView:
    """A view that does nothing, at no cost."""

    def scan(self, index, stamp, pose, odom, true_pose) -> None:
        pass

    def milestone(self, milestone_id, pose) -> None:
        pass

    def match(self, milestone_id, milestone_pose, robot_pose, accepted, reason) -> None:
        pass

    def anchors_moved(self, ids, poses) -> None:
        pass

    def close(self) -> None:
        pass
