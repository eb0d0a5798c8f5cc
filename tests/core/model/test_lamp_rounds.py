"""The lamp rounds of a scene fit (:func:`illumon.model.fit._refit_without_lamp_frames`, issue 29): a round whose
frames left out change only by frames at the prior, now and in the last judgement, refits nothing; any other change
is refitted as before. The rounds' judgements are scripted (``history_lamps`` replaced), so only the rule is tested.
"""

from __future__ import annotations

import numpy as np
import pytest
from illumon.model import fit as fit_mod
from illumon.model.lamps import LAMP_PRIOR
from illumon.observations import Observations

N = 40


@pytest.fixture
def history() -> Observations:
    rng = np.random.default_rng(0)
    return Observations([f"f{i}" for i in range(N)], ["a", "b", "c"], rng.uniform(0.1, 0.9, (N, 3, 3)),
                        [""] * N)


class _Model:
    history_estimate = ()


def _rounds(monkeypatch, obs: Observations, judgements: list[np.ndarray]) -> list[int]:
    """Run the rounds with the given ``non_daylight`` per judgement; the number of frames of each refit."""
    script = iter(judgements)
    monkeypatch.setattr(fit_mod, "history_lamps", lambda model, o: next(script))
    fits: list[int] = []

    def fit_once(day, estimate=None, rows=None):
        assert estimate is obs and len(rows) == len(day.frames)
        fits.append(len(day.frames))
        return _Model()

    fit_mod._refit_without_lamp_frames(_Model(), obs, fit_once)
    return fits


def _judgement(lamp: dict[int, float]) -> np.ndarray:
    nd = np.full(N, 0.05)
    nd[0] = 0.9  # a frame more likely lamp-lit than not: the rounds act
    for i, v in lamp.items():
        nd[i] = v
    return nd


def test_coin_flips_at_the_prior_are_not_refitted(monkeypatch, history):
    first = _judgement({1: LAMP_PRIOR + 0.004, 2: LAMP_PRIOR - 0.003})  # frames 0 and 1 out
    second = _judgement({1: LAMP_PRIOR - 0.002, 2: LAMP_PRIOR + 0.001})  # 1 back in, 2 out: both at the prior
    assert _rounds(monkeypatch, history, [first, second, second]) == [N - 2]


def test_a_frame_that_moved_far_is_refitted(monkeypatch, history):
    first = _judgement({1: LAMP_PRIOR + 0.004, 2: 0.10})
    second = _judgement({1: LAMP_PRIOR + 0.004, 2: LAMP_PRIOR + 0.005})  # 2 was far below: a real change
    assert _rounds(monkeypatch, history, [first, second, second]) == [N - 2, N - 3]
    near = _judgement({1: LAMP_PRIOR + 0.004, 2: LAMP_PRIOR - 0.005})  # 2 at the prior, kept
    far = _judgement({1: LAMP_PRIOR + 0.004, 2: 0.6})  # then judged far above it: a real change
    assert _rounds(monkeypatch, history, [near, far, far]) == [N - 2, N - 3]


def test_borderline_zero_refits_every_change(monkeypatch, history):
    monkeypatch.setattr(fit_mod, "BORDERLINE", 0.0)
    first = _judgement({1: LAMP_PRIOR + 0.004, 2: LAMP_PRIOR - 0.003})
    second = _judgement({1: LAMP_PRIOR - 0.002, 2: LAMP_PRIOR + 0.001})
    assert _rounds(monkeypatch, history, [first, second, second]) == [N - 2, N - 2]


def test_unchanged_rounds_stop_as_before(monkeypatch, history):
    first = _judgement({1: 0.7})
    assert _rounds(monkeypatch, history, [first, first]) == [N - 2]
    assert _rounds(monkeypatch, history, [np.full(N, 0.3)]) == []  # no frame above 0.5: nothing left out
