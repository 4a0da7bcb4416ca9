"""The probes' convex hull: how far a fitted peak lies beyond it, and the soft prior that
brings a runaway fit back to its edge.

Why a module of its own: beyond the last probe column a sensor shows only the inner flank
of its bump, so what the data say about it there is a question of geometry, not of the peak
model. A live update keeps the hull as it goes (``ProbeHull``) because qhull over every
probe on every touch cost more than all the statuses together.
"""

from __future__ import annotations

import numpy as np

# Scale of the soft prior that a peak fitted beyond the probes' hull lies at its edge, in
# units of the outside margin max(h, w)/2: 1.0 pulled a sensor truly 2.8 mm past a corner
# 2 mm in; 2.0 left more of the last-column sensors runaway (fresh seeds 300-359).
HULL_PRIOR = 1.5


class ProbeHull:
    """The hull of the probes seen so far, kept across live updates.

    New touches inside it leave it as it is; new touches outside it only need the hull of
    its corners and themselves. The caller rules out collinear probes first.
    """

    def __init__(self) -> None:
        self._k = 0  # probes it covers
        self._edges: np.ndarray | None = None
        self._corners: np.ndarray | None = None

    def edges(self, probes: np.ndarray) -> np.ndarray | None:
        """(E, 3) edges n.x + c <= 0 (n unit, outward) of the hull of ``probes`` (K, 2),
        which extend the probes of the last call; None if qhull finds them flat."""
        K = len(probes)
        if self._edges is None:
            from scipy.spatial import ConvexHull, QhullError

            pts = np.unique(probes, axis=0)
            try:
                hull = ConvexHull(pts)
            except QhullError:
                # Flat to qhull's precision although the scatter test passed (a probe at
                # 1e18 mm in a damaged file): no hull, judged as collinear probes.
                return None
            self._edges, self._corners = hull.equations, pts[hull.vertices]
        elif self._k != K:
            new = probes[self._k :]
            if not (new @ self._edges[:, :2].T + self._edges[:, 2] <= 1e-9).all():
                self._corners, self._edges = small_hull(np.vstack([self._corners, new]))
        self._k = K
        return self._edges


def small_hull(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corners and edges (n.x + c <= 0 inside, n unit and outward) of the convex hull of a
    few points that are not all on one line.

    A live update's hull is its old corners plus the new touch: a handful of points, for
    which a monotone chain in plain Python is cheaper than setting up qhull. The caller
    has ruled out collinear probes.
    """
    p = sorted(set(map(tuple, pts.tolist())))

    def chain(seq):
        out: list = []
        for q in seq:
            while len(out) >= 2:
                (ax, ay), (bx, by) = out[-2], out[-1]
                if (bx - ax) * (q[1] - ay) - (by - ay) * (q[0] - ax) > 0:
                    break
                out.pop()  # not a left turn: b is inside or on the edge a-q
            out.append(q)
        return out[:-1]

    corners = np.array(chain(p) + chain(p[::-1]))  # counter-clockwise
    edge = np.roll(corners, -1, axis=0) - corners
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.hypot(edge[:, 0], edge[:, 1])[:, None]
    return corners, np.column_stack([normal, -(normal * corners).sum(axis=1)])


def hull_distance(eq: np.ndarray | None, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Signed distance (mm, >0 outside) of each xy from the hull with edges ``eq``, the
    unit outward normal of the edge that distance is measured to, and collinear?"""
    if eq is None:
        return np.full(len(xy), np.inf), np.full((len(xy), 2), np.nan), True
    with np.errstate(invalid="ignore"):
        d = xy @ eq[:, :2].T + eq[:, 2]
    j = np.argmax(np.where(np.isfinite(d), d, -np.inf), axis=1)
    return d.max(axis=1), eq[j, :2], False


def pull_into_hull(
    xy: np.ndarray, cov: np.ndarray, dist_out: np.ndarray, normal: np.ndarray, margin: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Soft prior that a peak fitted beyond the probes' hull lies near the hull's edge.

    A sensor just past the last probe column shows only the inner flank of its bump, so the
    fit can slide its peak outwards almost freely (Patch B's last TX wire: 0.5 mm beyond the
    probes, fitted 4-7 mm beyond with a 5-13 mm sd). The prior is Gaussian in the distance
    beyond the hull, centred on the edge with sd ``margin`` (footprint-scaled), combined
    with the fit's own variance along the edge's normal; inside the hull it does nothing.
    Returns the new xy, the per-axis variance and the fit's own sd along the normal.
    """
    with np.errstate(invalid="ignore"):
        s2n = np.einsum("ni,nij,nj->n", normal, cov, normal)
    trace = np.trace(cov, axis1=1, axis2=2)
    use = np.isfinite(dist_out) & (dist_out > 0) & np.isfinite(s2n) & (s2n >= 0)
    s2n = np.where(use, s2n, 0.0)
    m2 = margin**2
    keep = m2 / (m2 + s2n)  # the fraction of the outward distance the data keep
    shift = np.where(use, dist_out * (1.0 - keep), 0.0)
    xy = xy - np.where(use[:, None], normal, 0.0) * shift[:, None]
    post = s2n * keep
    var = np.maximum((trace - s2n + post) / 2.0, 0.0)
    return xy, var, np.sqrt(s2n)
