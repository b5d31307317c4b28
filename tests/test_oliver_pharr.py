"""Oliver-Pharr analysis (certificate/oliver_pharr.py) on synthetic unloading curves of known power laws."""

import math

import numpy as np
import pytest

from elastoplast.certificate.oliver_pharr import first_unloading, oliver_pharr, projected_area
from elastoplast.errors import InputError

E, NU, R = 200e3, 0.3, 50.0
E_STAR = E / (1 - NU**2)


def hertz(h):
    """A rigid paraboloid on an elastic half-space: F = (4/3) E* sqrt(R) h^(3/2)."""
    return 4.0 / 3.0 * E_STAR * math.sqrt(R) * np.asarray(h) ** 1.5


def test_elastic_hertz_unloading_recovers_e_star():
    # load to h_max and unload along the same curve: S = 2 E* sqrt(R h), h_c = h/2, A = pi R h, E_r = E* (exactly)
    h_max = 0.01
    h = np.concatenate([np.linspace(0.001, h_max, 10), np.linspace(h_max, 0.001, 12)[1:]])
    out = oliver_pharr(h, hertz(h), shape="paraboloid", E=E, nu=NU, radius=R)
    assert out["S"] == pytest.approx(2 * E_STAR * math.sqrt(R * h_max), rel=1e-8)
    assert out["m"] == pytest.approx(1.5, rel=1e-8) and out["h_f"] == pytest.approx(0.0, abs=1e-10)
    assert out["h_c"] == pytest.approx(h_max / 2, rel=1e-8)
    assert out["A"] == pytest.approx(math.pi * R * h_max, rel=1e-8)
    assert out["E_r"] == pytest.approx(E_STAR, rel=1e-8)
    assert out["E_star"] == pytest.approx(E_STAR, rel=1e-15)


@pytest.mark.parametrize("m", [1.2, 1.5, 2.0])
def test_power_law_with_residual_imprint(m):
    alpha, h_f, h_max = 3.0e5, 0.004, 0.012
    load = np.linspace(0.002, h_max, 6)
    unload = np.linspace(h_max, 0.006, 9)
    h = np.concatenate([load, unload[1:], [0.005, 0.0055]])  # then a reload: the first unloading ends there
    F_max = alpha * (h_max - h_f) ** m
    F = np.concatenate([F_max * (load / h_max) ** 1.7, alpha * (unload[1:] - h_f) ** m, alpha * (np.array([0.005, 0.0055]) - h_f) ** m])
    out = oliver_pharr(h, F, shape="cone", E=E, nu=NU, half_angle=70.3)
    S = m * alpha * (h_max - h_f) ** (m - 1)
    h_c = h_max - 0.75 * F_max / S
    A = math.pi * math.tan(math.radians(70.3)) ** 2 * h_c**2
    assert out["step_peak"] == 5
    assert out["S"] == pytest.approx(S, rel=1e-7)
    assert out["h_c"] == pytest.approx(h_c, rel=1e-7)
    assert out["hardness"] == pytest.approx(F_max / A, rel=1e-6)
    assert out["E_r"] == pytest.approx(math.sqrt(math.pi) * S / (2 * math.sqrt(A)), rel=1e-6)


def test_two_point_unloading_uses_the_secant():
    out = oliver_pharr([1.0, 2.0, 1.9], [1.0, 4.0, 3.0], shape="sphere", E=E, nu=NU, radius=R)
    assert out["S"] == pytest.approx(10.0) and out["alpha"] is None and "secant" in out["fit"]
    h_c = 2.0 - 0.75 * 4.0 / 10.0
    assert out["A"] == pytest.approx(math.pi * (2 * R * h_c - h_c**2))


def test_no_unloading_and_bad_input():
    assert oliver_pharr([1.0, 2.0], [1.0, 2.0], shape="sphere", E=E, nu=NU, radius=R) is None
    assert first_unloading([1, 2, 3, 2, 1, 2]) == (2, 4)
    with pytest.raises(InputError) as info:
        oliver_pharr([1.0, 2.0], [1.0], shape="sphere", E=E, nu=NU, radius=R)
    assert info.value.field == "depths"
    with pytest.raises(InputError) as info:
        oliver_pharr([1.0, 2.0, 1.5], [1.0, 2.0, 1.0], shape="flat", E=E, nu=NU)
    assert info.value.field == "obstacle.shape"
    assert projected_area("paraboloid", 0.1, radius=2.0) == pytest.approx(2 * math.pi * 2.0 * 0.1)
