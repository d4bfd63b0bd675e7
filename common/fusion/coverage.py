"""Which cameras of a world frame could have reported an object, when some live camera's
frame is missing from it (late, or not sent).

A robot that a camera's image border cuts shows there as a blob without its marker,
and the blob's disk (centroid pulled inwards, radius from the visible area) can lie
wholly inside that image, so the cut test lets it through. Normally another camera sees
the robot whole, with its marker, and the blob falls inside the robot's footprint
(:func:`~ovis.common.fusion.merge.fuse`). While that camera's frame is missing, nothing
tells the blob from an obstacle: a blob that lies within a robot's reach of its image
border (the disk of twice the largest robot radius round it is not wholly inside: the
robot's centre is within one radius of the blob's, its footprint within two) and that a
missing camera sees whole is left out of that world frame; the missing camera reports it
when its frames come.

The same question keeps identities: a world obstacle that no camera of the frame could
have reported is not counted as unseen (it is in a late camera's area), so a camera late
for longer than ``lost_frames`` does not cost its obstacles their world ids.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.fusion.sightings import MARKER, R, Sightings, X, Y, Z

__all__ = ["View", "reportable", "without_suspects"]

Mask = NDArray[np.bool_]


class View(Protocol):
    """A camera's view: is each disk wholly inside its image, with the cut margin
    (:meth:`ovis.common.fusion.accuracy.AccuracyMap.whole`)."""

    def whole(self, x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike,
              radius_cm: ArrayLike) -> Mask: ...  # fmt: skip


def _seen_by_any(
    views: Mapping[str, View],
    cameras: Collection[str],
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    r: ArrayLike,
) -> Mask:
    """Per disk: wholly in the view of one of ``cameras`` at least."""
    out = np.zeros(np.shape(x), bool)
    for name in cameras:
        view = views.get(name)
        if view is not None:
            out |= view.whole(x, y, z, r)
    return out


def reportable(
    views: Mapping[str, View],
    present: Collection[str],
    missing: Collection[str],
    robot_radius_cm: float,
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    r: ArrayLike,
) -> Mask:
    """Per object (disk at x, y, z of radius r): would a camera that gave its frame have
    reported it (wholly in its view, and not a blob left out by :func:`without_suspects`)?"""
    x, y, z, r = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (x, y, z, r)))
    late = _seen_by_any(views, missing, x, y, z, r) if robot_radius_cm > 0 else None
    out = np.zeros(x.shape, bool)
    for name in present:
        view = views.get(name)
        if view is None:
            continue
        seen = view.whole(x, y, z, r)
        if late is not None and late.any():
            seen &= view.whole(x, y, z, np.full_like(r, 2 * robot_radius_cm)) | ~late
        out |= seen
    return out


def without_suspects(
    views: Mapping[str, View],
    found: Sightings,
    missing: Collection[str],
    robot_radius_cm: float,
) -> Sightings:
    """Sightings (of any cameras) without the blobs that may be a cut robot (module
    docstring) and that a ``missing`` camera sees whole."""
    d = found.data
    blob = np.isnan(d[:, MARKER])
    if robot_radius_cm <= 0 or not missing or not blob.any():
        return found
    x, y, z, r = d[blob, X], d[blob, Y], d[blob, Z], d[blob, R]
    late = _seen_by_any(views, missing, x, y, z, r)
    if not late.any():
        return found
    cams = found.cam[blob]
    deep = np.zeros(len(x), bool)
    reach = np.full(len(x), 2 * robot_radius_cm)
    for c in set(cams[late].tolist()):
        sel = late & (cams == c)
        view = views.get(found.cameras[c])
        deep[sel] = True if view is None else view.whole(x[sel], y[sel], z[sel], reach[sel])
    suspect = late & ~deep
    if not suspect.any():
        return found
    keep = np.ones(len(d), bool)
    keep[np.flatnonzero(blob)[suspect]] = False
    return Sightings(found.cameras, d[keep], found.robot[keep], found.cam[keep])
