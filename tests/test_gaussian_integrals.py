"""F_n(h) against mpmath (40 digits), the closed forms and the derivative rule dF_n/dh = −n F_{n−1}."""

from __future__ import annotations

import mpmath as mp
import numpy as np
import pytest
from scipy.special import erfc

from feeder.contact.gaussian_integrals import gaussian_integral, gaussian_integrals

mp.mp.dps = 40
H_GRID = np.linspace(-8.0, 12.0, 81)


def reference(n: float, h: float, upper: float | None = None) -> mp.mpf:
    """(1/√(2π)) ∫_h^upper (s − h)^n e^{−s²/2} ds in 40-digit arithmetic."""
    nn, hh = mp.mpf(n), mp.mpf(h)
    if upper is None:  # DLMF 12.5.1 with mpmath's own parabolic cylinder function
        return mp.gamma(nn + 1) / mp.sqrt(2 * mp.pi) * mp.exp(-hh * hh / 4) * mp.pcfd(-nn - 1, hh)
    f = lambda s: (s - hh) ** nn * mp.exp(-s * s / 2)  # noqa: E731
    return mp.quad(f, [hh, (hh + upper) / 2, mp.mpf(upper)]) / mp.sqrt(2 * mp.pi)


@pytest.mark.parametrize("n", [0.0, 1.0, 1.5, 0.5])  # 0.5 is used by the Newton solve
def test_matches_mpmath_to_1e12_on_whole_range(n: float) -> None:
    values = gaussian_integral(n, H_GRID)
    exact = np.array([float(reference(n, h)) for h in H_GRID])
    assert np.max(np.abs(values - exact) / exact) <= 1e-12


@pytest.mark.parametrize(("h", "upper"), [(0.0, 3.0), (4.0, 6.0), (5.0, 5.5), (-2.0, 7.0), (6.9, 7.0)])
@pytest.mark.parametrize("n", [0.0, 1.0, 1.5])
def test_truncated_at_highest_summit(n: float, h: float, upper: float) -> None:
    value = float(gaussian_integral(n, h, upper))
    assert value == pytest.approx(float(reference(n, h, upper)), rel=1e-12)


def test_zero_above_upper_limit() -> None:
    assert np.all(gaussian_integral(1.5, [7.0, 8.0], 7.0) == 0.0)


def test_closed_forms_and_shapes() -> None:
    h = np.array([[-3.0, 0.0], [2.0, 5.0]])
    f0, f1 = gaussian_integrals((0.0, 1.0), h)
    assert f0.shape == (2, 2)
    np.testing.assert_allclose(f0, 0.5 * erfc(h / np.sqrt(2)), rtol=1e-15)
    phi = np.exp(-(h**2) / 2) / np.sqrt(2 * np.pi)
    np.testing.assert_allclose(f1, phi - h * f0, rtol=1e-12)


@pytest.mark.parametrize("n", [1.0, 1.5])
def test_derivative_rule(n: float) -> None:
    h = np.linspace(-4, 8, 13)
    step = 1e-5
    numeric = (gaussian_integral(n, h + step) - gaussian_integral(n, h - step)) / (2 * step)
    np.testing.assert_allclose(numeric, -n * gaussian_integral(n - 1.0, h), rtol=1e-7)


def test_rejects_h_below_validated_range() -> None:
    with pytest.raises(ValueError, match="h must be"):
        gaussian_integral(1.5, -9.0)
