"""Signatures and the four comparison methods, against the paper's equations."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.scenario import load_scenario
from drivers.simulator import Simulator
from milestones.methods import CCA, DCT, ED, HWT, _best, make_method
from milestones.overlap import overlap_sums
from milestones.signature import make_signature, sample_step

RNG = np.random.default_rng(42)


def smooth_profile(n=180, seed=0):
    """A range profile with walls, corners and a gap: what a room looks like to a laser."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.normal(0, 0.15, n)) + 3.0
    x[rng.integers(0, n - 10):][:10] += 2.0
    return np.clip(x, 0.3, 7.9)


# --- signature ------------------------------------------------------------------------------

def test_no_return_beams_are_clamped_to_max_range():
    r = np.array([1.0, np.inf, np.nan, 0.0, -1.0, 9.0, 2.0])
    sig = make_signature(r, max_range=8.0, length=7)
    np.testing.assert_allclose(sig, [1.0, 8.0, 8.0, 8.0, 8.0, 8.0, 2.0])


def test_resampling_keeps_the_profile_and_endpoints():
    r = np.linspace(1.0, 5.0, 181)
    sig = make_signature(r, 8.0, 180)
    assert sig.shape == (180,)
    np.testing.assert_allclose(sig, np.linspace(1.0, 5.0, 180), atol=1e-12)
    assert math.isclose(sample_step(181, math.radians(1), 180), math.radians(180 / 179))


def test_circular_resampling_wraps():
    r = 2.0 + np.sin(np.arange(360) * 2 * np.pi / 360)
    sig = make_signature(r, 8.0, 180, circular=True)
    np.testing.assert_allclose(sig, 2.0 + np.sin(np.arange(180) * 2 * np.pi / 180), atol=1e-4)


@pytest.mark.parametrize("ranges, message", [
    ([], "at least 2 beams"),
    ([np.nan] * 10, "without any return"),
    ([np.inf, 0.0, 8.0], "without any return"),
    (np.ones((2, 2, 2)), r"\(N,\) or \(M, N\)"),
])
def test_bad_scans_get_a_value_error_that_says_so(ranges, message):
    with pytest.raises(ValueError, match=message):
        make_signature(np.asarray(ranges, dtype=float), 8.0)


@pytest.mark.parametrize("method", [ED(180), CCA(180), DCT(180, 18), HWT(180, 3)])
def test_methods_reject_wrong_length_and_nan(method):
    good = smooth_profile()
    with pytest.raises(ValueError, match="length 180"):
        method.encode(good[:170])
    with pytest.raises(ValueError, match="finite"):
        method.encode(np.full(180, np.nan))
    with pytest.raises(ValueError, match="length 180"):
        method.search(good[:100], method.encode(good[None]), max_shift=10)


# --- equations 1 to 4 ----------------------------------------------------------------------

def test_ed_is_equation_1():
    x, y = smooth_profile(seed=1), smooth_profile(seed=2)
    literal = math.sqrt(sum((a - b) ** 2 for a, b in zip(x, y, strict=True)))
    assert math.isclose(ED.euclidean(x, y), literal, rel_tol=1e-12)
    assert math.isclose(ED(180).distance(x, y[None])[0], literal / math.sqrt(180), rel_tol=1e-12)


@pytest.mark.parametrize("n", [180, 181, 360])
def test_dct_is_equation_3_computed_literally(n):
    x = RNG.uniform(0.5, 8.0, n)
    F = n
    j = np.arange(1, n + 1)
    lam = np.where(np.arange(1, F + 1) == 1, 1 / math.sqrt(n), math.sqrt(2 / n))
    y = np.array([lam[i - 1] * np.sum(x * np.cos(np.pi * (2 * j - 1) * (i - 1) / (2 * n)))
                  for i in range(1, F + 1)])
    np.testing.assert_allclose(DCT(n, n).encode(x), y, atol=1e-11)
    np.testing.assert_allclose(DCT(n, 18).encode(x), y[:18], atol=1e-11)


def test_dct_restoration_is_equation_4():
    n, F = 180, 18
    x = smooth_profile()
    dct = DCT(n, F)
    yv = dct.encode(x)
    i = np.arange(1, n + 1)[:, None]
    jj = np.arange(1, F + 1)[None, :]
    lam = np.where(jj == 1, 1 / math.sqrt(n), math.sqrt(2 / n))
    literal = (lam * yv[None, :] * np.cos(np.pi * (2 * i - 1) * (jj - 1) / (2 * n))).sum(axis=1)
    np.testing.assert_allclose(dct.decode(yv), literal, atol=1e-11)
    assert math.isclose(dct.compression, 0.9)


def test_reconstruction_from_all_coefficients_is_exact():
    x = smooth_profile()
    np.testing.assert_allclose(DCT(180, 180).decode(DCT(180, 180).encode(x)), x, atol=1e-12)
    for level in range(0, 6):
        hwt = HWT(180, level)
        import pywt
        coeffs = hwt.coefficients(x)
        back = coeffs[0] if level == 0 else pywt.waverec(coeffs, "haar", mode="periodization")
        np.testing.assert_allclose(back[:180], x, atol=1e-12)
    np.testing.assert_allclose(HWT(180, 0).decode(HWT(180, 0).encode(x)), x)


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 7), st.integers(0, 10_000))
def test_hwt_preserves_euclidean_distance_at_every_level(level, seed):
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0.1, 8.0, (2, 180))
    hwt = HWT(180, level)
    cx = np.concatenate(hwt.coefficients(x))
    cy = np.concatenate(hwt.coefficients(y))
    assert len(cx) == hwt.padded_length and hwt.padded_length % 2**level == 0
    assert math.isclose(np.linalg.norm(cx - cy), np.linalg.norm(x - y), rel_tol=1e-12)


def test_naive_haar_without_padding_would_not_preserve_distance():
    """Why HWT pads: 180 has only two factors of 2, so level 3 of plain pywt drifts."""
    import pywt
    drift = []
    for x, y in RNG.uniform(0.1, 8.0, (50, 2, 180)):
        cx = np.concatenate(pywt.wavedec(x, "haar", mode="periodization", level=3))
        cy = np.concatenate(pywt.wavedec(y, "haar", mode="periodization", level=3))
        drift.append(abs(np.linalg.norm(cx - cy) / np.linalg.norm(x - y) - 1))
    assert max(drift) > 1e-3


def test_compression_of_hwt_and_make_method():
    assert HWT(180, 3).num_features == 23  # 184 / 8
    assert make_method("hwt", 180, keep=0.1).level == 3
    assert make_method("dct", 180, keep=0.1).num_features == 18
    with pytest.raises(ValueError, match="unknown method"):
        make_method("fft", 180)


# --- heading search -----------------------------------------------------------------------

@pytest.mark.parametrize("k", [-40, -7, 0, 3, 25])
def test_cca_finds_a_known_shift_exactly(k):
    base = smooth_profile(260, seed=5)
    stored = base[40:220]
    query = base[40 + k:220 + k]  # q[i] = s[i + k]
    m = CCA(180).search(query, stored[None], max_shift=60)
    assert m.shift[0] == k
    assert m.score[0] < 1e-12


@pytest.mark.parametrize("k", [-70, -1, 13, 89])
def test_circular_shift_is_found_with_full_overlap(k):
    s = smooth_profile(180, seed=9)
    q = np.roll(s, -k)  # q[i] = s[i + k mod 180]
    for method in (ED(180), CCA(180), DCT(180, 18), HWT(180, 3)):
        m = method.search(q, method.encode(s[None]), max_shift=90, circular=True)
        assert m.shift[0] == k and m.score[0] < 1e-6, method.name


def test_overlap_sums_equal_the_literal_loops():
    q = smooth_profile(seed=3)
    s = np.stack([smooth_profile(seed=4), smooth_profile(seed=5), np.full(180, 2.0)])
    shifts = np.arange(-30, 31)
    sums = overlap_sums(q, s, shifts)
    rms, rho = sums.rms(), sums.rho()
    for m in range(2):
        for j, k in enumerate(shifts):
            i = np.arange(max(0, -k), min(180, 180 - k))
            a, b = q[i], s[m, i + k]
            assert math.isclose(rms[m, j], math.sqrt(np.mean((a - b) ** 2)), rel_tol=1e-9)
            assert math.isclose(rho[m, j], np.corrcoef(a, b)[0, 1], rel_tol=1e-9)
    assert (rho[2] == 0.0).all()  # a flat signature correlates with nothing


def _best_in_numpy(curve):
    """The heading search's pick in NumPy, the spec the compiled one must match."""
    i = np.argmin(curve, axis=1)
    rows = np.arange(len(curve))
    inner = (i > 0) & (i < curve.shape[1] - 1)
    a = curve[rows, np.clip(i - 1, 0, None)]
    b = curve[rows, i]
    c = curve[rows, np.clip(i + 1, None, curve.shape[1] - 1)]
    den = a - 2.0 * b + c
    delta = np.where(inner & (den > 1e-15), 0.5 * (a - c) / np.where(den > 1e-15, den, 1.0), 0.0)
    return i, b, np.clip(delta, -0.5, 0.5)


def test_the_best_shift_and_its_refinement_are_numpys():
    rng = np.random.default_rng(1)
    curve = rng.random((40, 25))
    curve[0, :] = 0.5  # a tie everywhere: the first shift
    curve[1, 0] = -1.0  # least at the first shift: no refinement
    curve[2, -1] = -1.0  # and at the last
    curve[3:5] += 1.0  # above the minima set next
    curve[3, 10:13] = [0.2, 0.1, 0.2]  # a symmetric minimum: refined by nothing
    curve[4, 4:7] = [0.3, -1.0, -0.9]  # leaning right
    shifts = np.arange(-12, 13)
    m = _best(curve, shifts)
    i, score, delta = _best_in_numpy(curve)
    assert np.array_equal(m.shift, shifts[i]) and np.array_equal(m.score, score)
    assert np.allclose(m.refined, shifts[i] + delta, rtol=0, atol=1e-15)
    assert m.shift[0] == -12 and m.refined[1] == -12 and m.refined[2] == 12
    assert m.refined[3] == -1 and 0.4 < m.refined[4] + 7 < 0.5  # 0.6 / 1.4 of a sample


def test_all_methods_find_the_heading_of_a_turned_real_scan():
    """A simulated robot turned on the spot by 12 degrees: every method recovers the turn."""
    sim = Simulator(load_scenario("lab"))
    home = sim.scenario.stations.home
    turned = home + [0, 0, math.radians(12)]
    r = sim.ranges_at(np.vstack([home, turned]))
    sig = make_signature(r, 8.0, 180)
    step = sample_step(181, math.radians(1), 180)
    for method in (ED(180), CCA(180), DCT(180, 18), HWT(180, 3)):
        m = method.search(sig[1], method.encode(sig[:1]), max_shift=45)
        assert math.isclose(m.refined[0] * step, math.radians(12), abs_tol=math.radians(1.5)), \
            method.name
