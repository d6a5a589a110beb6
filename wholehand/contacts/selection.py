"""Vectorised candidate selection shared by the estimators: threshold and top-K per link."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.intp]


def top_k_per_link(link: IntArray, distance: npt.NDArray[np.floating], k: int) -> IntArray:
    """Indices of at most ``k`` rows per link, smallest distance first (stable, no Python loop).

    Args:
        link: (M,) link index of each candidate.
        distance: (M,) signed distance of each candidate [m].
        k: maximum rows kept per link (>= 1).

    Returns:
        Indices into the candidates, ordered by link then distance.
    """
    if link.size == 0:
        return np.zeros(0, dtype=np.intp)
    order = np.lexsort((distance, link))
    sorted_link = link[order]
    starts = np.flatnonzero(np.r_[True, sorted_link[1:] != sorted_link[:-1]])
    group_start = np.repeat(starts, np.diff(np.r_[starts, sorted_link.size]))
    rank = np.arange(sorted_link.size) - group_start
    return order[rank < k]
