"""Which resting face an object lies on for the next table-top grasp candidates."""

from __future__ import annotations

from wholehand.models.resting import RestingFace


class FaceSchedule:
    """Which resting face the next table-top candidates use, so that the grasps cover the faces.

    An object lands on any of its faces, and a reacher can only use grasps made on the face it
    lies on, so each face gets an equal share of the ``count`` grasps asked for (rounded up):
    the next candidates go to the face that has fewest candidates tried among those short of
    their share (ties: the likelier face), or among all faces once every face has its share.

    Args:
        faces: The object's resting faces, most probable first.
        count: Grasps asked for in all.
    """

    def __init__(self, faces: list[RestingFace], count: int) -> None:
        if not faces:
            raise ValueError("a face schedule needs at least one resting face")
        self.faces = faces
        self.share = -(-max(count, 1) // len(faces))
        self.tried = [0] * len(faces)
        self.found = [0] * len(faces)

    def next(self) -> int:
        """Index into ``faces`` of the face of the next candidates."""
        short = [i for i, n in enumerate(self.found) if n < self.share]
        pool = short or list(range(len(self.faces)))
        return min(pool, key=lambda i: (self.tried[i], i))

    def record(self, face: int, tried: int, found: int) -> None:
        """Count ``tried`` candidates on ``face`` that gave ``found`` grasps."""
        self.tried[face] += tried
        self.found[face] += found
