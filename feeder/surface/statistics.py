"""Summit statistics of a height map and the GW equivalent surface (paper eqs. 1, 3, 12–14).

Steps, all vectorised:

1. **Plane removal**: the least-squares plane ``a + b·i + c·j`` over the pixel grid is
   subtracted (on a full regular grid the normal equations decouple, so the fit is three
   sums). Heights are then measured from the mean plane (mean height 0).
2. **Summits**: interior pixels strictly higher than all 8 neighbours (paper §IV.C).
   Border pixels are never summits. The search runs in row blocks: a pixel must beat its
   left and right neighbours and the 3-wide maxima of the rows above and below.
3. **Sq** (eq. 13): RMS of all plane-removed heights. **μ** (eq. 12): mean summit height
   (above the mean plane). The std of the summit heights is reported beside Sq: the two
   differ (summits sit high and spread less), and the paper's σ uses Sq (eq. 14).
4. **η**: summit count / area of the interior pixels where a summit can be detected,
   ``(n0 − 2)(n1 − 2)·Δ0·Δ1``.
5. **R, local fit**: a quadratic ``z = a + b·x + c·y + d·x² + e·y² + f·x·y`` is fitted by
   least squares to the 3×3 neighbourhood of each summit. On the regular grid its
   curvatures are ``κ0 = 2d`` = the mean of the three second differences along axis 0,
   ``(z₋ − 2z₀ + z₊)/Δ0²``, and likewise ``κ1``. The summit's mean curvature is
   ``κ = (κ0 + κ1)/2`` and its radius ``R_i = −1/κ`` (exact for any paraboloid, the
   harmonic mean of the principal radii for an elliptic one). Summits whose fitted
   κ is not negative (a noise spike on a saddle) have no radius and are counted apart.
   ``mean_summit_radius_m`` is the mean of the R_i, as in the paper ("the mean radius is
   the average of all radius"); ``radius_from_mean_curvature_m = −1/mean(κ)`` is reported
   beside it (less sensitive to nearly flat summits).

Equivalent surface of two scans (eqs. 1, 3, §IV.C): 1/R = 1/R1 + 1/R2,
σ = √(Sq1² + Sq2²), μ = (μ1 + μ2)/2, summit density η = η1 + η2 (the paper sums the
asperity counts). One scan is taken as the rough surface against a smooth plane.

Resolution: on a grid of independent pixel values (pure noise) a pixel beats its 8
neighbours with probability 1/9, so η_noise = 1/(9·Δ0·Δ1) is the density pixel noise
gives. ``noise_summit_fraction = η/η_noise`` near 1 means the summits are pixel noise.
A low-pass (``low_pass``, the ISO 16610-61 areal Gaussian filter with transmission
exp(−π(α λc/λ)²), α = √(ln 2/π): 50 % at the cutoff wavelength λc) removes it.

Reference for synthetic tests: an isotropic Gaussian surface has ``(1/(6π√3))·m4/m2``
summits per unit area (Nayak 1971), with m2, m4 the profile spectral moments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feeder.surface.parameters import SurfaceParameters
from feeder.surface.reading import HeightMap

_BLOCK_ROWS = 128


@dataclass(frozen=True)
class SurfaceStatistics:
    """Statistics of one plane-removed scan (SI units; heights above the mean plane)."""

    sq_m: float
    summit_count: int
    summit_density_per_m2: float
    mean_summit_height_m: float
    summit_height_std_m: float
    mean_summit_radius_m: float
    radius_from_mean_curvature_m: float
    summits_without_radius: int
    highest_summit_m: float
    noise_summit_fraction: float
    """η / η_noise, η_noise = 1/(9 Δ0 Δ1) the summit density of pure pixel noise."""
    pixel_size_m: tuple[float, float]
    scan_size_m: tuple[float, float]
    source: str = ""
    channel: str = ""

    def surface_parameters(
        self, youngs_modulus_pa: float = 169e9, poisson_ratio: float = 0.28
    ) -> SurfaceParameters:
        """This scan as the GW rough surface against a smooth plane (σ = Sq, eq. 14)."""
        return SurfaceParameters(
            sigma_m=self.sq_m,
            summit_radius_m=self.mean_summit_radius_m,
            summit_density_per_m2=self.summit_density_per_m2,
            mean_summit_height_m=self.mean_summit_height_m,
            youngs_modulus_pa=youngs_modulus_pa,
            poisson_ratio=poisson_ratio,
        )


def remove_plane(heights: np.ndarray) -> np.ndarray:
    """Heights minus their least-squares plane over the pixel grid (a new array)."""
    n0, n1 = heights.shape
    i = np.arange(n0) - (n0 - 1) / 2.0
    j = np.arange(n1) - (n1 - 1) / 2.0
    mean0 = heights.mean(axis=1)  # mean of each row (position i)
    mean1 = heights.mean(axis=0)
    slope0 = float(i @ mean0) / float(i @ i)
    slope1 = float(j @ mean1) / float(j @ j)
    offset = float(mean0.mean())
    result = heights - (offset + slope0 * i)[:, None]
    result -= (slope1 * j)[None, :]
    return result


def low_pass(heights: np.ndarray, pixel_size_m: tuple[float, float], cutoff_m: float) -> np.ndarray:
    """Areal Gaussian low-pass (module docstring) of a plane-removed map, by FFT (periodic)."""
    alpha = math.sqrt(math.log(2.0) / math.pi)
    k0 = np.fft.fftfreq(heights.shape[0], pixel_size_m[0])  # 1/wavelength, 1/m
    k1 = np.fft.rfftfreq(heights.shape[1], pixel_size_m[1])
    k2 = k0[:, None] ** 2 + k1[None, :] ** 2
    transmission = np.exp(-math.pi * (alpha * cutoff_m) ** 2 * k2)
    return np.fft.irfft2(np.fft.rfft2(heights) * transmission, s=heights.shape)


def find_summits(heights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the pixels strictly higher than their 8 neighbours."""
    n0, _ = heights.shape
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    for start in range(1, n0 - 1, _BLOCK_ROWS):
        stop = min(start + _BLOCK_ROWS, n0 - 1)
        block = heights[start - 1 : stop + 1]
        centre = block[1:-1, 1:-1]
        mask = centre > block[1:-1, :-2]
        mask &= centre > block[1:-1, 2:]
        row_max = np.maximum(block[:, :-2], block[:, 2:])
        np.maximum(row_max, block[:, 1:-1], out=row_max)
        mask &= centre > row_max[:-2]
        mask &= centre > row_max[2:]
        r, c = np.nonzero(mask)
        rows.append(r + start)
        cols.append(c + 1)
    return np.concatenate(rows), np.concatenate(cols)


def summit_curvatures(
    heights: np.ndarray, rows: np.ndarray, cols: np.ndarray, pixel_size_m: tuple[float, float]
) -> np.ndarray:
    """Mean curvature κ = (κ0 + κ1)/2 (1/m) of the 3×3 least-squares quadratic at each summit."""
    d0, d1 = pixel_size_m
    second0 = np.zeros(rows.shape)
    second1 = np.zeros(rows.shape)
    for k in (-1, 0, 1):
        second0 += heights[rows - 1, cols + k] - 2.0 * heights[rows, cols + k] + heights[rows + 1, cols + k]
        second1 += heights[rows + k, cols - 1] - 2.0 * heights[rows + k, cols] + heights[rows + k, cols + 1]
    return 0.5 * (second0 / (3.0 * d0 * d0) + second1 / (3.0 * d1 * d1))


def surface_statistics(height_map: HeightMap, remove_tilt: bool = True) -> SurfaceStatistics:
    """Summit statistics of a height map (module docstring gives the definitions)."""
    heights = remove_plane(height_map.heights_m) if remove_tilt else height_map.heights_m
    flat = heights.ravel()
    sq = math.sqrt(float(flat @ flat) / flat.size)
    rows, cols = find_summits(heights)
    summit_heights = heights[rows, cols]
    curvature = summit_curvatures(heights, rows, cols, height_map.pixel_size_m)
    capped = curvature < 0
    n0, n1 = heights.shape
    d0, d1 = height_map.pixel_size_m
    area = (n0 - 2) * (n1 - 2) * d0 * d1
    count = int(rows.size)
    nan = float("nan")
    return SurfaceStatistics(
        sq_m=sq,
        summit_count=count,
        summit_density_per_m2=count / area,
        mean_summit_height_m=float(summit_heights.mean()) if count else nan,
        summit_height_std_m=float(summit_heights.std()) if count else nan,
        mean_summit_radius_m=float(np.mean(-1.0 / curvature[capped])) if capped.any() else nan,
        radius_from_mean_curvature_m=float(-1.0 / curvature.mean()) if count else nan,
        summits_without_radius=int(count - np.count_nonzero(capped)),
        highest_summit_m=float(summit_heights.max()) if count else nan,
        noise_summit_fraction=count / area * 9.0 * d0 * d1,
        pixel_size_m=height_map.pixel_size_m,
        scan_size_m=height_map.scan_size_m,
        source=height_map.source,
        channel=height_map.channel,
    )


def equivalent_surface(
    first: SurfaceStatistics,
    second: SurfaceStatistics,
    youngs_modulus_pa: float = 169e9,
    poisson_ratio: float = 0.28,
) -> SurfaceParameters:
    """GW equivalent surface of two scanned bodies (eqs. 1, 3; η summed, μ averaged)."""
    return SurfaceParameters(
        sigma_m=math.hypot(first.sq_m, second.sq_m),
        summit_radius_m=1.0 / (1.0 / first.mean_summit_radius_m + 1.0 / second.mean_summit_radius_m),
        summit_density_per_m2=first.summit_density_per_m2 + second.summit_density_per_m2,
        mean_summit_height_m=0.5 * (first.mean_summit_height_m + second.mean_summit_height_m),
        youngs_modulus_pa=youngs_modulus_pa,
        poisson_ratio=poisson_ratio,
    )
