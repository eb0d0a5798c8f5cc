"""CCT and Duv through the tabulated Planckian locus (Ohno 2013), against colour-science."""

import colour
import numpy as np
from illumon.daylight import ohno2013


def test_cct_duv_round_trip_against_ohno():
    cct = np.array([3000.0, 5000.0, 6500.0, 12000.0])
    duv = np.array([0.004, -0.002, 0.0, 0.006])
    xy = ohno2013.xy_from_cct_duv(cct, duv)
    back_cct, back_duv = ohno2013.cct_duv_from_xy(xy)
    assert np.max(np.abs(back_cct - cct) / cct) < 2e-4
    assert np.max(np.abs(back_duv - duv)) < 2e-5
    ohno = colour.temperature.uv_to_CCT_Ohno2013(colour.xy_to_UCS_uv(xy))
    assert np.max(np.abs(ohno[:, 0] - cct) / cct) < 1e-3
    assert np.max(np.abs(ohno[:, 1] - duv)) < 1e-4


def test_planck_locus_matches_colour_blackbody():
    # Independent truth: colour-science's blackbody (its own c₂) through the same observer, at tabulated mireds.
    loc = ohno2013.planck_locus()
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    for mired in (500.0, 250.0, 150.0, 100.0):
        xyz = colour.sd_to_XYZ(colour.sd_blackbody(1e6 / mired, cmfs.shape), cmfs, method="Integration")
        uv = colour.xy_to_UCS_uv(colour.XYZ_to_xy(xyz))
        i = int(np.argmin(np.abs(loc.mired - mired)))
        assert np.max(np.abs(loc.uv[i] - uv)) < 1e-8, (mired, loc.uv[i], uv)


def test_locus_table_is_plancks_law_bit_for_bit() -> None:
    """The table's blackbody spectra, computed in one buffer (issue 29), equal the plain expression bit for bit (the
    table computed afresh, so its matrix product runs with the same BLAS threads as the reference's)."""
    mired, uv = ohno2013._planck_table()[:2]  # computed, not read from the disk cache (illumon._tables)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    wl = np.asarray(cmfs.wavelengths, dtype=float) * 1e-9
    t = 1e6 / mired
    xyz = (1.0 / (wl[None, :] ** 5 * np.expm1(1.4388e-2 / (wl[None, :] * t[:, None])))) @ np.asarray(cmfs.values)
    den = xyz[:, 0] + 15 * xyz[:, 1] + 3 * xyz[:, 2]
    np.testing.assert_array_equal(uv, np.stack([4 * xyz[:, 0] / den, 6 * xyz[:, 1] / den], axis=1))


def test_locus_interpolation_is_np_interp_bit_for_bit() -> None:
    """The four columns interpolated with one interval search (issue 29) equal ``np.interp`` of each, bit for bit:
    inside the table, on its nodes, at and beyond its ends, for NaN and ±inf, in any shape."""
    p = ohno2013.planck_locus()
    rng = np.random.default_rng(0)
    cases = [rng.uniform(20, 600, 3000), rng.uniform(0, 1100, (7, 50)), p.mired[rng.integers(0, p.mired.size, 500)],
             1e6 / (1e6 / rng.uniform(5, 1000, 1000)), np.array([5.0, 1000.0, 4.999, 1000.0001, p.mired[-1]]),
             np.array([np.nan, np.inf, -np.inf, 150.0]), np.array(150.3)]
    for m in cases:
        got = ohno2013._locus_at(p, m)
        want = [np.interp(m, p.mired, col) for col in (p.uv[:, 0], p.uv[:, 1], p.normal[:, 0], p.normal[:, 1])]
        for g, w in zip(got, want, strict=True):
            assert g.shape == np.shape(w)
            np.testing.assert_array_equal(g, w)
