"""The scalar paths of :mod:`fmcwlog.geometry` against its array formulas, bit for bit.

One pose (a float64 (3,) array) is composed, inverted and wrapped on Python floats with
:mod:`math`; the same functions given (1, 3) arrays run numpy's ufuncs, the formulas as they
were. Both must give the same bits: the outputs of a run may not change with the fast paths.
That rests on numpy's float64 sin/cos being the C library's, which holds without AVX-512 (with
it numpy uses SVML, 1 ulp apart); the first test says whether it holds on this machine, and the
bitwise tests fall back to 1 ulp where it does not.
"""

import math
from decimal import Decimal, localcontext

import numpy as np
from helpers import numpy_trig_is_libm, same_bits
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.geometry import between, compose, inverse, transform_points, wrap_angle

_RNG = np.random.default_rng(20261122)
# angles of every size the estimator meets, and the awkward ones: ±π, multiples of π/2, tiny, huge
_ANGLES = np.concatenate([
    _RNG.uniform(-4.0, 4.0, 200_000), _RNG.uniform(-1e-3, 1e-3, 50_000), _RNG.normal(0.0, 1e-9, 20_000),
    _RNG.uniform(-1e4, 1e4, 50_000),
    np.array([0.0, -0.0, math.pi, -math.pi, math.pi / 2, -math.pi / 2, 2 * math.pi, 1e-300, 5e-324, 1e300]),
    np.nextafter(math.pi, 0.0) * np.array([1.0, -1.0]), np.nextafter(-math.pi, 0.0) * np.array([1.0, -1.0]),
])
finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
angle = st.one_of(st.floats(-10.0, 10.0), st.sampled_from([math.pi, -math.pi, 0.0, -0.0, 2 * math.pi]),
                  st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False))
pose = st.tuples(finite, finite, angle).map(lambda p: np.array(p, dtype=float))


def _sin_cos_to_60_digits(x: float) -> tuple[Decimal, Decimal]:
    """sin and cos of the float's exact binary value by their Taylor series in 60-digit decimals:
    the true values, by no float arithmetic and no C library (|x| <= 4: the terms fall below 1e-60
    within 80 of them)."""
    with localcontext() as ctx:
        ctx.prec = 60
        x2, term, s, c = Decimal(x) ** 2, Decimal(x), Decimal(0), Decimal(0)
        for n in range(1, 160, 2):  # term = (-1)^k x^n / n!, n = 2k + 1; cos's term is term * n / x
            s += term
            c += term * n / Decimal(x) if x else (Decimal(1) if n == 1 else Decimal(0))
            term = -term * x2 / ((n + 1) * (n + 2))
        return s, c


def test_numpy_float64_sin_cos_are_the_c_library_on_this_machine():
    """The scalar paths take sin/cos from the C library (math), the array paths from numpy: the
    bitwise tests below rest on the two being equal where :func:`numpy_trig_is_libm`, and at most
    2 ulp apart (``same_bits``' fallback) where not. The independent fact: each is within 1 ulp of
    the true value (a 60-digit series) over angles of the estimator's sizes and the awkward ones
    (near ±π, π/2, tiny), so the two cannot be more than 2 ulp apart on any machine."""
    rng = np.random.default_rng(7)
    angles = np.concatenate([rng.uniform(-4.0, 4.0, 1500), rng.uniform(-1e-3, 1e-3, 200), rng.normal(0.0, 1e-9, 50),
                             [0.0, math.pi, -math.pi, math.pi / 2, -math.pi / 2, 1e-300, 5e-324, 3.0, -2.5],
                             np.nextafter(math.pi, 0.0) * np.array([1.0, -1.0])])
    np_sin, np_cos = np.sin(angles), np.cos(angles)
    for i, a in enumerate(angles.tolist()):
        true_sin, true_cos = _sin_cos_to_60_digits(a)
        for got, true, what in ((math.sin(a), true_sin, "math.sin"), (math.cos(a), true_cos, "math.cos"),
                                (float(np_sin[i]), true_sin, "np.sin"), (float(np_cos[i]), true_cos, "np.cos")):
            assert abs(Decimal(got) - true) <= Decimal(math.ulp(float(true))), (what, a, got, true)
    if numpy_trig_is_libm():  # and where the helper says so, they are the same bits here too
        assert np_sin.tolist() == [math.sin(a) for a in angles.tolist()]
        assert np_cos.tolist() == [math.cos(a) for a in angles.tolist()]


def test_wrap_angle_of_a_float_is_the_array_formula():
    """Python's float % against numpy's remainder over 320 000 angles and the edges (±π, ±0, huge)."""
    got = np.array([wrap_angle(a) for a in _ANGLES.tolist()])
    want = wrap_angle(_ANGLES)
    assert got.tobytes() == want.tobytes()  # no trig: bit for bit on any machine
    assert type(wrap_angle(1.0)) is np.float64 and type(wrap_angle(np.float64(1.0))) is np.float64
    for special in (math.inf, -math.inf, math.nan):
        with np.errstate(invalid="ignore"):
            assert np.isnan(wrap_angle(special)) and np.isnan(wrap_angle(np.array([special]))[0])


def test_compose_inverse_between_over_many_poses():
    """320 000 pose pairs (the angle sample as yaws), each through the scalar and the array path."""
    n = len(_ANGLES)
    a = np.column_stack([_RNG.uniform(-50, 50, (n, 2)), _ANGLES])
    b = np.column_stack([_RNG.uniform(-50, 50, (n, 2)), _RNG.permutation(_ANGLES)])
    sample = _RNG.choice(n, 20_000, replace=False)  # the scalar path one pose at a time: a sample
    assert same_bits(np.array([compose(a[i], b[i]) for i in sample]), compose(a, b)[sample])
    assert same_bits(np.array([inverse(a[i]) for i in sample]), inverse(a)[sample])
    assert same_bits(np.array([between(a[i], b[i]) for i in sample]), compose(inverse(a), b)[sample])


@settings(max_examples=400, deadline=None)
@given(pose, pose)
def test_scalar_paths_match_the_array_formulas(a, b):
    assert same_bits(compose(a, b), compose(a[None], b[None])[0])
    assert same_bits(inverse(a), inverse(a[None])[0])
    assert same_bits(between(a, b), compose(inverse(a[None]), b[None])[0])
    pts = np.array([[1.5, -2.0], [0.0, 0.0], [-1e3, 7.25]])
    assert same_bits(transform_points(a, pts), transform_points(np.repeat(a[None], 3, 0), pts))


def test_non_finite_yaws_take_the_array_path():
    """``math.cos(inf)`` raises where numpy gives NaN: the scalar path steps aside."""
    with np.errstate(invalid="ignore"):
        for yaw in (math.inf, -math.inf, math.nan):
            a = np.array([1.0, 2.0, yaw])
            b = np.array([0.5, -0.5, 0.1])
            assert np.isnan(compose(a, b)).all() and np.isnan(inverse(a)).all()
            assert np.isnan(between(a, b)).all() and np.isnan(transform_points(a, np.ones((2, 2)))).all()


def test_float32_points_are_transformed_in_float64_as_before():
    """A Python float times float32 points stays float32 (NEP 50): such points take the array path."""
    pts = _RNG.uniform(-30, 30, (500, 2)).astype(np.float32)
    a = np.array([0.3, -1.2, 0.7])
    assert transform_points(a, pts).tobytes() == transform_points(a[None], pts).tobytes()


def test_the_fast_paths_keep_the_geometry():
    """Independent facts, not the formulas again: a pose composed with its inverse is the identity,
    and a point moved by a pose keeps its distance to the pose's origin."""
    for a in _RNG.uniform([-10, -10, -4], [10, 10, 4], (200, 3)):
        np.testing.assert_allclose(compose(a, inverse(a)), 0.0, atol=1e-12)
        np.testing.assert_allclose(between(a, a), 0.0, atol=1e-12)
        p = transform_points(a, np.array([[3.0, 4.0]]))[0]
        assert math.isclose(math.hypot(p[0] - a[0], p[1] - a[1]), 5.0, rel_tol=1e-12)
