"""What the pipeline tells a view, and the view that does nothing when nobody watches."""

from __future__ import annotations

from typing import Protocol

from vmp.types import FloatArray

__all__ = ["NullView", "View"]


class View(Protocol):
    """Receives plain arrays and values as the map is built (``viz`` implements it)."""

    def segment(self, index: int, stamp: float, segment: int, anchor_id: int,
                anchor_pose: FloatArray) -> None:
        """A segment opened at scan ``index``, anchored at a milestone."""

    def scan(self, index: int, stamp: float, pose: FloatArray, odom: FloatArray,
             true_pose: FloatArray | None, segment: int, rel_pose: FloatArray,
             end_points: FloatArray, hits: FloatArray, metrics: dict[str, float]) -> None:
        """A scan inserted: its pose in its segment's frame, end points in its own frame."""

    def milestone(self, milestone_id: int, pose: FloatArray) -> None: ...

    def match(self, milestone_id: int, milestone_pose: FloatArray, robot_pose: FloatArray,
              accepted: bool, reason: str) -> None: ...

    def anchors_moved(self, ids: FloatArray, poses: FloatArray) -> None: ...

    def event(self, text: str, level: str = "INFO") -> None: ...

    def saved_milestones(self, ids: FloatArray, poses: FloatArray) -> None:
        """The milestones of a saved map being localized in."""

    def localization(self, index: int, stamp: float, state: str, pose: FloatArray | None,
                     hypotheses: FloatArray, true_pose: FloatArray | None) -> None:
        """A scan localized in a saved map: the state, the pose (when localized) and every
        place followed ``(H, 3)``, in the saved map's frame."""

    def grid(self, cells: FloatArray, resolution: float, origin: tuple[float, float]) -> None: ...

    def hold(self) -> None:
        """Keep showing what was logged until the user stops it (a served viewer)."""

    def close(self) -> None: ...


class NullView:
    """A view that does nothing, at no cost."""

    def segment(self, index, stamp, segment, anchor_id, anchor_pose) -> None:
        pass

    def scan(self, index, stamp, pose, odom, true_pose, segment, rel_pose, end_points, hits,
             metrics) -> None:
        pass

    def milestone(self, milestone_id, pose) -> None:
        pass

    def match(self, milestone_id, milestone_pose, robot_pose, accepted, reason) -> None:
        pass

    def anchors_moved(self, ids, poses) -> None:
        pass

    def event(self, text, level="INFO") -> None:
        pass

    def saved_milestones(self, ids, poses) -> None:
        pass

    def localization(self, index, stamp, state, pose, hypotheses, true_pose) -> None:
        pass

    def grid(self, cells, resolution, origin) -> None:
        pass

    def hold(self) -> None:
        pass

    def close(self) -> None:
        pass
