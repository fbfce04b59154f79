"""Surface statistics against closed forms: spectra with known Sq, Nayak's summit density,
paraboloids with known radius, planes, and the equivalent-surface rules (eqs. 1, 3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from feeder.surface.reading import HeightMap
from feeder.surface.statistics import (
    equivalent_surface,
    find_summits,
    remove_plane,
    summit_curvatures,
    surface_statistics,
)


def band_limited_surface(
    n: int, shortest_px: float, longest_px: float, sq: float, seed: int
) -> tuple[np.ndarray, float]:
    """Periodic isotropic surface with a flat spectrum on the wavelength band, unit-modulus
    Fourier coefficients and random phases, scaled so its RMS height is exactly ``sq``.

    Returns the heights and Nayak's summit density (1/(6π√3))·m4/m2 per pixel², with the
    profile moments m2 = ½⟨k²⟩, m4 = ⅜⟨k⁴⟩ (isotropic averages over the modes used).
    """
    rng = np.random.default_rng(seed)
    k0 = np.fft.fftfreq(n)[:, None]
    k1 = np.fft.rfftfreq(n)[None, :]
    k = np.hypot(k0, k1)
    modes = (k >= 1 / longest_px) & (k <= 1 / shortest_px) & (k1 > 0) & (k1 < 0.5)
    count = int(modes.sum())
    amplitude = sq * math.sqrt(2.0 / count)  # each cosine has variance amplitude²/2
    coefficients = np.zeros(k.shape, complex)
    coefficients[modes] = 0.5 * n * n * amplitude * np.exp(2j * np.pi * rng.random(count))
    heights = np.fft.irfft2(coefficients, s=(n, n))
    wavenumber = 2 * np.pi * k[modes]
    m2 = 0.5 * np.mean(wavenumber**2)
    m4 = 0.375 * np.mean(wavenumber**4)
    return heights, m4 / m2 / (6 * math.pi * math.sqrt(3))


def test_sq_is_exact_for_a_known_spectrum() -> None:
    heights, _ = band_limited_surface(256, 8, 64, sq=1.5e-9, seed=1)
    stats = surface_statistics(HeightMap(heights, (2e-9, 2e-9), "synthetic"), remove_tilt=False)
    assert stats.sq_m == pytest.approx(1.5e-9, rel=1e-12)


@pytest.mark.parametrize("seed", [2, 3])
def test_summit_density_matches_nayak(seed: int) -> None:
    pixel = 5e-9
    heights, nayak_per_px2 = band_limited_surface(512, 8, 32, sq=1e-9, seed=seed)
    stats = surface_statistics(HeightMap(heights, (pixel, pixel), "synthetic"))
    assert stats.summit_count > 1000
    assert stats.summit_density_per_m2 == pytest.approx(nayak_per_px2 / pixel**2, rel=0.10)
    # plane removal on an (almost) plane-free surface changes Sq very little
    assert stats.sq_m == pytest.approx(1e-9, rel=0.01)


def test_summits_agree_with_a_maximum_filter() -> None:
    rng = np.random.default_rng(4)
    heights = ndimage.gaussian_filter(rng.normal(size=(300, 257)), 2.0)
    heights[100, 100:103] = 10.0  # a plateau: three equal pixels are not strict summits
    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    neighbours = ndimage.maximum_filter(heights, footprint=ring, mode="constant", cval=np.inf)
    expected = set(zip(*np.nonzero(heights > neighbours), strict=True))
    rows, cols = find_summits(heights)
    assert set(zip(rows.tolist(), cols.tolist(), strict=True)) == expected
    assert (100, 101) not in expected and len(expected) > 100


def test_paraboloid_caps_give_their_exact_radius() -> None:
    radius = 40e-9
    d0, d1 = 2e-9, 3e-9
    x = np.arange(64)[:, None] * d0
    y = np.arange(48)[None, :] * d1
    # a 2x2 lattice of paraboloid caps (cell 32 x 24 px), apex exactly on a pixel
    cx = (np.round(x / d0) // 32 * 32 + 16) * d0
    cy = (np.round(y / d1) // 24 * 24 + 12) * d1
    heights = 5e-9 - ((x - cx) ** 2 + (y - cy) ** 2) / (2 * radius)
    stats = surface_statistics(HeightMap(heights, (d0, d1), "paraboloids"), remove_tilt=False)
    assert stats.summit_count == 4
    assert stats.mean_summit_radius_m == pytest.approx(radius, rel=1e-9)
    assert stats.radius_from_mean_curvature_m == pytest.approx(radius, rel=1e-9)
    assert stats.mean_summit_height_m == pytest.approx(5e-9, rel=1e-12)
    assert stats.summit_height_std_m == pytest.approx(0.0, abs=1e-20)


def test_elliptic_paraboloid_gives_harmonic_mean_of_principal_radii() -> None:
    r0, r1, d = 30e-9, 90e-9, 1e-9
    x = (np.arange(21)[:, None] - 10) * d
    y = (np.arange(21)[None, :] - 10) * d
    heights = -(x**2) / (2 * r0) - y**2 / (2 * r1)
    rows, cols = find_summits(heights)
    curvature = summit_curvatures(heights, rows, cols, (d, d))
    assert (rows.tolist(), cols.tolist()) == ([10], [10])
    assert -1 / curvature[0] == pytest.approx(2 / (1 / r0 + 1 / r1), rel=1e-9)


def test_plane_removal_is_the_least_squares_plane() -> None:
    rng = np.random.default_rng(5)
    rough = rng.normal(size=(40, 30))
    i, j = np.meshgrid(np.arange(40), np.arange(30), indexing="ij")
    tilted = rough + 3.0 + 0.2 * i - 0.7 * j
    design = np.column_stack([np.ones(i.size), i.ravel(), j.ravel()])
    coefficients, *_ = np.linalg.lstsq(design, tilted.ravel(), rcond=None)
    expected = tilted - (design @ coefficients).reshape(tilted.shape)
    np.testing.assert_allclose(remove_plane(tilted), expected, atol=1e-12)
    np.testing.assert_allclose(remove_plane(tilted), remove_plane(rough), atol=1e-12)


def test_equivalent_surface_rules() -> None:
    pixel = 2e-9
    first = surface_statistics(HeightMap(band_limited_surface(128, 6, 30, 1e-9, 6)[0], (pixel, pixel), "a"))
    second = surface_statistics(HeightMap(band_limited_surface(128, 6, 30, 2e-9, 7)[0], (pixel, pixel), "b"))
    surface = equivalent_surface(first, second)
    assert surface.sigma_m == pytest.approx(math.sqrt(first.sq_m**2 + second.sq_m**2))
    assert 1 / surface.summit_radius_m == pytest.approx(
        1 / first.mean_summit_radius_m + 1 / second.mean_summit_radius_m
    )
    assert surface.summit_density_per_m2 == pytest.approx(
        first.summit_density_per_m2 + second.summit_density_per_m2
    )
    assert surface.mean_summit_height_m == pytest.approx(
        (first.mean_summit_height_m + second.mean_summit_height_m) / 2
    )
    single = first.surface_parameters()
    assert (single.sigma_m, single.summit_radius_m) == (first.sq_m, first.mean_summit_radius_m)
