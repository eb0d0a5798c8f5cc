"""The lamp rounds of a scene fit (:func:`illumon.model.fit._refit_without_lamp_frames`, issue 29): a round whose
frames left out change only by frames at the prior, now and in the last judgement, refits nothing; any other change
is refitted as before. The rounds' judgements are scripted (``history_lamps`` replaced), so only the rule is tested.
"""

from __future__ import annotations

import numpy as np
import pytest
from illumon.model import fit as fit_mod
from illumon.model.lamps import LAMP_PRIOR, HistoryJudgement
from illumon.observations import Observations

N = 40


@pytest.fixture
def history() -> Observations:
    rng = np.random.default_rng(0)
    return Observations([f"f{i}" for i in range(N)], ["a", "b", "c"], rng.uniform(0.1, 0.9, (N, 3, 3)),
                        [""] * N)


class _Model:
    history_estimate = ()
    fit_frames = None  # the frames its reflectances were fitted on; None: not known, the share is not judged


def _rounds(monkeypatch, obs: Observations, judgements: list[np.ndarray], fit_frames: np.ndarray | None = None
            ) -> list[int]:
    """Run the rounds with the given ``non_daylight`` per judgement, the first model fitted on ``fit_frames``; the
    number of frames of each refit."""
    script = iter(judgements)
    monkeypatch.setattr(fit_mod, "history_lamps", lambda model, o: HistoryJudgement(next(script), np.empty((N, 3))))
    fits: list[int] = []

    def fit_once(day, estimate=None, rows=None):
        assert estimate is obs and len(rows) == len(day.frames)
        fits.append(len(day.frames))
        return _Model()

    first = _Model()
    first.fit_frames = fit_frames
    _, judged = fit_mod._refit_without_lamp_frames(first, obs, fit_once)
    # the model returned comes with its judgement unless the last round refitted it
    assert (judged is not None) == (len(fits) < fit_mod.LAMP_ROUNDS)
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


def test_lamp_lit_frames_too_few_of_the_fit_are_not_refitted(monkeypatch, history):
    """Issue 29: the first round leaves frames out only when those judged lamp-lit make up at least
    ``MIN_LAMP_SHARE`` of the frames the reflectances were fitted on."""
    one = _judgement({1: LAMP_PRIOR + 0.1})  # frame 0 above 0.5, frame 1 above the prior
    assert _rounds(monkeypatch, history, [one, one], fit_frames=np.arange(N)) == [N - 2]  # 1 of 40: 2.5 %
    assert _rounds(monkeypatch, history, [one], fit_frames=np.arange(1, N)) == []  # frame 0 not in the fit
    monkeypatch.setattr(fit_mod, "MIN_LAMP_SHARE", 0.05)
    assert _rounds(monkeypatch, history, [one], fit_frames=np.arange(N)) == []  # 2.5 % < 5 %
    two = _judgement({1: 0.8})
    assert _rounds(monkeypatch, history, [two, two], fit_frames=np.arange(N)) == [N - 2]  # 5 %
    # later rounds are judged as before: the refitted model's own fit holds no lamp-lit frame, yet a real change
    # of the frames left out is refitted
    third = _judgement({1: 0.8, 2: 0.7})
    assert _rounds(monkeypatch, history, [two, third, third], fit_frames=np.arange(N)) == [N - 2, N - 3]


def test_rounds_that_end_on_a_refit_leave_it_unjudged(monkeypatch, history):
    judgements = [_judgement({k: 0.8 for k in range(1, r + 2)}) for r in range(fit_mod.LAMP_ROUNDS + 1)]
    assert _rounds(monkeypatch, history, judgements) == [N - 2 - r for r in range(fit_mod.LAMP_ROUNDS)]
