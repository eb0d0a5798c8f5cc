"""The disk cache of per-machine tables (:mod:`illumon._tables`, issue 29)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from illumon import _tables
from illumon.daylight import cie, ohno2013
from illumon.model import general, lamps


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(_tables.CACHE_ENV, str(tmp_path))
    return tmp_path


def _counting(values):
    calls = []

    def compute():
        calls.append(1)
        return values

    return compute, calls


def test_read_back_bit_for_bit(cache):
    values = (np.random.default_rng(0).normal(size=(7, 5)), np.arange(4, dtype=np.int64))
    compute, calls = _counting(values)
    first = _tables.cached_arrays("t", (b"x", 1.5), (_tables.__file__,), compute)
    second = _tables.cached_arrays("t", (b"x", 1.5), (_tables.__file__,), compute)
    assert len(calls) == 1
    for a, b, c in zip(values, first, second, strict=True):
        assert a.dtype == c.dtype and a.shape == c.shape
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    assert len(list(cache.glob("t-*.npz"))) == 1


def test_inputs_name_the_file(cache):
    compute, calls = _counting((np.zeros(3),))
    for part in (b"a", b"b", b"a"):
        _tables.cached_arrays("t", (part,), (_tables.__file__,), compute)
    assert len(calls) == 2


def test_off_damaged_and_unwritable(cache, monkeypatch):
    values = (np.ones((2, 2)),)
    compute, calls = _counting(values)
    _tables.cached_arrays("t", (), (_tables.__file__,), compute)
    (path,) = cache.glob("t-*.npz")
    path.write_bytes(b"not a zip")  # damaged: computed again (and rewritten)
    np.testing.assert_array_equal(_tables.cached_arrays("t", (), (_tables.__file__,), compute)[0], values[0])
    assert len(calls) == 2
    monkeypatch.setenv(_tables.CACHE_ENV, "")  # off
    _tables.cached_arrays("t", (), (_tables.__file__,), compute)
    assert len(calls) == 3
    blocker = cache / "file"
    blocker.write_text("")
    monkeypatch.setenv(_tables.CACHE_ENV, str(blocker / "sub"))  # cannot be created
    np.testing.assert_array_equal(_tables.cached_arrays("t", (), (_tables.__file__,), compute)[0], values[0])
    assert len(calls) == 4


def test_cached_tables_equal_computed(cache):
    """Each table the cache holds is the computation's, bit for bit, when computed and when read back."""
    fields = ("mired", "uv", "duv_dm", "normal")
    computed = ohno2013._planck_table()
    for _ in range(2):
        loc = ohno2013.PlanckLocus(*_tables.cached_arrays("planck-locus", (), (ohno2013.__file__,),
                                                            ohno2013._planck_table))
        for name, want in zip(fields, computed, strict=True):
            np.testing.assert_array_equal(getattr(loc, name), want)
    for _ in range(2):
        np.testing.assert_array_equal(
            _tables.cached_arrays("cie-lamps", general._LAMPS, (general.__file__,), general._lamp_table)[0],
            general._lamp_table()[0])
        for got, want in zip(_tables.cached_arrays("daylight-locus-duv", (), (cie.__file__,), cie._locus_duv_computed),
                             cie._locus_duv_computed(), strict=True):
            np.testing.assert_array_equal(got, want)


def test_lattice_table_from_disk(cache):
    """A lamp lattice read back by a process that did not compute it equals the computed one."""
    rng = np.random.default_rng(3)
    centres, logw = rng.normal(0, 0.1, (30, 2)), np.full(30, -np.log(30))
    step, start, count = np.array([0.008, 0.008]), np.array([-40, -35]), np.array([70, 60])
    lamps._tables.clear()
    first = lamps._lattice_table(centres, logw, 0.02, step, start, count).copy()
    lamps._tables.clear()  # as a new process: only the disk holds it
    second = lamps._lattice_table(centres, logw, 0.02, step, start, count)
    lamps._tables.clear()
    assert len(list(cache.glob("lamp-lattice-*.npz"))) == 1
    np.testing.assert_array_equal(first, second)
    axes = [np.arange(-64, 32) * step[0], np.arange(-64, 32) * step[1]]
    np.testing.assert_array_equal(second, lamps._lattice_logdensity(axes, centres, logw, 0.02)[24:94, 29:89])


def test_pruned_least_recently_used(cache, monkeypatch):
    """The folder is kept under MAX_BYTES after each write, least recently used first; reading a table uses it."""
    monkeypatch.setattr(_tables, "MAX_BYTES", 3 * 8_500)  # three of these tables (~8.3 kB each)
    compute, calls = _counting((np.zeros(1000),))
    src = (_tables.__file__,)

    def path(k: int):
        return cache / f"t-{_tables._key('t', (k,), src)}.npz"

    for k in range(3):
        _tables.cached_arrays("t", (k,), src, compute)
        os.utime(path(k), (1000.0 + k, 1000.0 + k))  # table k used at time 1000 + k
    _tables.cached_arrays("t", (0,), src, compute)  # read: table 0 is now the most recently used
    assert len(calls) == 3 and path(0).stat().st_mtime > 2000
    _tables.cached_arrays("t", (3,), src, compute)  # a fourth: table 1, the least recently used, goes
    assert len(calls) == 4 and not path(1).exists() and all(path(k).exists() for k in (0, 2, 3))
