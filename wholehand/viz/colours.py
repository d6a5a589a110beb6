"""Colour scales of the scene: force magnitudes (discrete, with a legend) and the hand's distance
to the nearest contact."""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.viz.arrows import FORCE_ARROW_MIN_N

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

FORCE_COLOURMAP = "plasma"
"""Matplotlib colour map of the force magnitude."""
FORCE_COLOUR_BINS = 8
"""Number of discrete colours of the force scale (one arrow pool per colour)."""
DISTANCE_COLOURMAP = "viridis_r"
"""Matplotlib colour map of the hand's distance to the nearest contact (near = yellow)."""
DISTANCE_RANGE_M = 0.05
"""Distance mapped to the far end of the distance colour map [m]."""


@dataclass(frozen=True)
class ColourScale:
    """Discrete colour scale of force magnitudes over [f_min, f_max] [N]."""

    f_min: float = FORCE_ARROW_MIN_N
    """Magnitude at the low end (the arrow threshold) [N]."""
    f_max: float = 5.0
    """Magnitude at the high end; larger forces take the last colour [N]."""
    n_bins: int = FORCE_COLOUR_BINS
    cmap: str = FORCE_COLOURMAP

    def __post_init__(self) -> None:
        if not (
            np.isfinite(self.f_min) and np.isfinite(self.f_max) and self.f_max > self.f_min >= 0
        ):
            raise ConfigError(
                f"ColourScale: need 0 <= f_min < f_max (finite) [N], "
                f"got {self.f_min!r}, {self.f_max!r}"
            )
        if self.n_bins < 1:
            raise ConfigError(f"ColourScale: n_bins must be >= 1, got {self.n_bins!r}")

    @classmethod
    def for_forces(cls, magnitudes: npt.ArrayLike, f_min: float = FORCE_ARROW_MIN_N) -> ColourScale:
        """From f_min to the largest magnitude rounded up to whole newtons (>= f_min + 1)."""
        m = np.asarray(magnitudes, dtype=float)
        top = float(np.ceil(m.max())) if m.size else 0.0
        return cls(f_min=f_min, f_max=max(top, f_min + 1.0))

    def bin(self, magnitude: npt.ArrayLike) -> IntArray:
        """(N,) colour-bin index of each magnitude, clipped to [0, n_bins - 1]."""
        u = (np.asarray(magnitude, dtype=float) - self.f_min) / (self.f_max - self.f_min)
        return np.clip(np.floor(u * self.n_bins), 0, self.n_bins - 1).astype(np.intp)

    def bin_rgb(self) -> FloatArray:
        """(n_bins, 3) RGB in [0, 1] of every bin (the colour map at the bin centres)."""
        from matplotlib import colormaps

        centres = (np.arange(self.n_bins) + 0.5) / self.n_bins
        return np.asarray(colormaps[self.cmap](centres))[:, :3]

    def rgb(self, magnitude: npt.ArrayLike) -> FloatArray:
        """(N, 3) RGB in [0, 1] of each magnitude."""
        return self.bin_rgb()[self.bin(magnitude)]

    def bin_edges(self) -> FloatArray:
        """(n_bins + 1,) magnitudes at the bin edges [N]."""
        return np.linspace(self.f_min, self.f_max, self.n_bins + 1)

    def legend_png(self, width_px: int = 140, height_px: int = 260) -> bytes:
        """A vertical colour bar with magnitude ticks, as PNG bytes (matplotlib, Agg)."""
        from matplotlib.colors import BoundaryNorm, ListedColormap
        from matplotlib.figure import Figure

        dpi = 100
        fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, facecolor="white")
        ax = fig.add_axes((0.12, 0.05, 0.22, 0.82))
        edges = self.bin_edges()
        cmap = ListedColormap(self.bin_rgb())
        norm = BoundaryNorm(edges, cmap.N)
        from matplotlib.cm import ScalarMappable

        bar = fig.colorbar(
            ScalarMappable(norm=norm, cmap=cmap), cax=ax, ticks=edges[:: max(1, self.n_bins // 4)]
        )
        bar.ax.tick_params(labelsize=8)
        ax.set_title("|f| [N]", fontsize=9, loc="left", pad=6)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
        return buf.getvalue()


def distance_to_nearest_contact(points: FloatArray, contact_p: FloatArray) -> FloatArray:
    """(P,) distance of each point to the nearest contact point [m]; inf where there is none."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    contact_p = np.asarray(contact_p, dtype=float).reshape(-1, 3)
    if contact_p.shape[0] == 0:
        return np.full(points.shape[0], np.inf)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(contact_p).query(points)
    return np.asarray(d, dtype=float)


def distance_rgb(
    distance: FloatArray, d_max: float = DISTANCE_RANGE_M, cmap: str = DISTANCE_COLOURMAP
) -> FloatArray:
    """(P, 3) RGB in [0, 1] of distances [m], clipped to [0, d_max] (inf takes the far colour)."""
    from matplotlib import colormaps

    u = np.clip(np.nan_to_num(np.asarray(distance, dtype=float), posinf=d_max) / d_max, 0.0, 1.0)
    return np.asarray(colormaps[cmap](u))[:, :3]
