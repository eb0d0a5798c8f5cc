"""A refit's estimates in bounded pieces (issue 29): the scene model's estimate of a history a chunk at a time equals
the estimate of every frame at once, and a lamp round's refit that estimates the whole history once gives the rows,
training summary and identifiability of a fit of its daylight frames alone.

History: :func:`illumon.simulation.effects.hide_effect` (``off_locus_illuminant``, seed 10 001 as in
``test_lamps.py``), so the model carries lamp verdicts and :func:`illumon.model.lamps.apply_lamps` runs.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from illumon.model import fit_scene_model, lamps, scene
from illumon.model.fit import _fit_fixed_camera
from illumon.observations import Observations
from illumon.simulation.effects import hide_effect


@pytest.fixture(scope="module")
def lamp_history(shared_data):
    from illumon.simulation import datasets

    css = datasets.load_camera("Canon_300D")
    obs = hide_effect("off_locus_illuminant", "Canon_300D", 10001).observations
    # measured standard errors too, so the chunks' extra variance is exercised
    obs = Observations(obs.frames, obs.patches, obs.values, obs.times, 0.002 * np.abs(obs.values))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit_scene_model(obs, css)
    return obs, css, model


def _close(a: dict, b: dict) -> None:
    """Equal to rounding (relative to each array's largest value: a covariance's cross terms cancel): a frame's
    numbers do not depend on the frames beside it, but the matrix products' rounding may depend on how many rows
    they have (BLAS kernels)."""
    for k in a:
        x, y = np.asarray(a[k], dtype=float), np.asarray(b[k], dtype=float)
        np.testing.assert_array_equal(np.isfinite(x), np.isfinite(y), err_msg=k)
        scale = float(np.max(np.abs(y[np.isfinite(y)]), initial=0.0))
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9 * scale, err_msg=k)


def _arrays(res, cols) -> dict:
    out = {k: getattr(res, k) for k in ("spectra", "xy", "cct", "duv", "white", "gains", "exposures")}
    out.update({f"info_{k}": res.info[k] for k in scene._FRAME_INFO})
    out.update({f"col_{k}": v for k, v in cols.items()})
    return out


def test_chunked_estimate_equals_one_piece(lamp_history, monkeypatch):
    obs, _, model = lamp_history
    assert model.lamps, "the history's model judges lamps"
    whole_res, whole_cols = model.estimate(obs)
    monkeypatch.setattr(scene, "ESTIMATE_CHUNK", 7)
    monkeypatch.setattr(lamps, "_MEANS_CHUNK", 5)
    res, cols = model.estimate(obs)
    assert len(obs.frames) > 3 * 7
    assert res.frames == whole_res.frames and res.times == whole_res.times
    assert set(cols) == set(whole_cols) and "non_daylight" in cols
    _close(_arrays(res, cols), _arrays(whole_res, whole_cols))
    np.testing.assert_array_equal(res.reflectances, whole_res.reflectances)


def test_a_refit_estimating_every_frame_equals_the_fit_of_its_frames(lamp_history):
    obs, css, _ = lamp_history
    rows = np.arange(0, len(obs.frames), 3)
    part = obs.subset(rows)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        alone, _ = _fit_fixed_camera(part, css)
        every, theta = _fit_fixed_camera(part, css, estimate=obs, rows=rows)
    assert theta.shape == (len(obs.frames), 3)
    assert every.training.pop("fit_seconds") >= 0 and alone.training.pop("fit_seconds") >= 0
    assert every.training.keys() == alone.training.keys()
    for k, v in alone.training.items():
        assert every.training[k] == (pytest.approx(v, rel=1e-9) if isinstance(v, float) else v), k
    assert every.identifiability.keys() == alone.identifiability.keys()
    np.testing.assert_array_equal(every.coefficients, alone.coefficients)
    res, cols = every.history_estimate
    assert res.frames == obs.frames
    # the frames the reflectances were fitted on, as frames of the history estimated
    np.testing.assert_array_equal(every.fit_frames, rows[alone.fit_frames])
    assert len(alone.fit_frames) == alone.training["frames_used_for_reflectances"]
    a = _arrays(*alone.history_estimate)
    _close(a, {k: v[rows] for k, v in _arrays(res, cols).items()})


def _linear_reference(solver, y, present, extra_var=None):
    """:meth:`FrameSolver.linear` as it was written before its sums became matrix products (einsums and
    ``np.linalg.inv``), with each frame's offset as three more unknowns of one 6 × 6 solve (its prior from
    :func:`flare_scales`) instead of integrated out: ``b`` is the first three, ``A`` the inverse of their
    covariance."""
    from illumon.model.solver import flare_scales
    from illumon.retrieval.common import censored

    yy = np.where(present[..., None], y, 0.0)
    var = (solver.noise_scale**2) * ((solver.rel * yy) ** 2 + solver.abs**2)
    if extra_var is not None:
        var = var + np.where(present[..., None], extra_var, 0.0)
    var = np.where(censored(yy, solver.abs, solver.white), 1e12, var)
    b = None
    for it in range(2 if solver.H is not None else 1):
        if it == 0:
            cinv = np.where(present[..., None], 1.0 / var, 0.0)
            gw = solver.G[None] * cinv[..., None]
        else:
            cov = np.einsum("pcekl,fk,fl->fpce", solver.H, b, b)
            cov[..., [0, 1, 2], [0, 1, 2]] += var
            cinv = np.where(present[..., None, None], np.linalg.inv(cov), 0.0)
            gw = np.einsum("fpce,pek->fpck", cinv, solver.G)
        a = np.einsum("fpck,pcl->fkl", gw, solver.G) + 1e-12 * np.eye(3)
        z = np.einsum("fpck,fpc->fk", gw, yy)
        if it == 0:
            scales = flare_scales(yy, cinv > 0, solver.flare_sd, solver.abs)
            u = None if scales is None else scales[:, :, None] * np.eye(3)  # o = U φ, φ standard normal
        if u is not None:
            cm = cinv if it == 1 else np.einsum("fpc,ce->fpce", cinv, np.eye(3))  # patch precisions, 3 × 3
            r = u.shape[2]
            n = np.zeros((len(yy), 3 + r, 3 + r))
            n[:, :3, :3] = a
            n[:, 3:, :3] = np.einsum("fcr,fpce,pek->frk", u, cm, solver.G)
            n[:, :3, 3:] = np.swapaxes(n[:, 3:, :3], 1, 2)
            n[:, 3:, 3:] = np.einsum("fcr,fpce,fes->frs", u, cm, u) + np.eye(r)
            rhs = np.concatenate([z, np.einsum("fcr,fpce,fpe->fr", u, cm, yy)], axis=1)
            b = np.linalg.solve(n, rhs[..., None])[:, :3, 0]
            a = np.linalg.inv(np.linalg.inv(n)[:, :3, :3])
        else:
            b = np.linalg.solve(a, z[..., None])[..., 0]
    return b, a


def test_frame_solver_linear_equals_the_einsum_reference(lamp_history):
    from illumon.model.solver import _inv3

    obs, _, model = lamp_history
    y = np.asarray(obs.values) / model.noise["scale"]
    present = np.all(np.isfinite(y), axis=-1)
    extra = obs.extra_variance() / model.noise["scale"] ** 2
    for cov, flare in ((model.covariance, 0.0), (None, 0.0), (model.covariance, 0.05), (None, 0.05)):
        solver = model.solver()
        solver.flare_sd = flare  # each frame's glare offset integrated out (FLARE_SD) or not
        if cov is None:
            solver.H = None
        for ev in (None, extra):
            b, a = solver.linear(y, present, ev)
            rb, ra = _linear_reference(solver, y, present, ev)
            np.testing.assert_allclose(b, rb, rtol=1e-10, atol=1e-12 * np.abs(rb).max())
            np.testing.assert_allclose(a, ra, rtol=1e-10, atol=1e-12 * np.abs(ra).max())
    m = np.random.default_rng(0).normal(size=(200, 3, 3))
    m = m @ m.transpose(0, 2, 1) + 1e-3 * np.eye(3)
    np.testing.assert_allclose(_inv3(m), np.linalg.inv(m), rtol=1e-9, atol=1e-9 * np.abs(np.linalg.inv(m)).max())


def test_fit_frames_are_the_reflectance_fits_subsample(lamp_history):
    """``fit_frames`` (issue 29, the lamp rounds' share): the frames a long history's reflectances were fitted on."""
    from illumon.model.identifiability import spread_subsample
    from illumon.retrieval.common import grey_world_mired

    obs, css, _ = lamp_history
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model, _ = _fit_fixed_camera(obs, css, max_fit_frames=10)
    want = spread_subsample(grey_world_mired(obs, css), 10)
    assert 0 < len(want) <= 10 < len(obs.frames)
    np.testing.assert_array_equal(model.fit_frames, want)
    assert model.training["frames_used_for_reflectances"] == len(want)


def test_the_fitted_models_lamp_verdicts_are_its_judgement_of_the_history(lamp_history):
    """The verdicts the lamp rounds stopped on are kept, not judged again (issue 29): they equal a judgement now."""
    import copy

    obs, _, model = lamp_history
    again = copy.copy(model)
    lamps.history_lamps(again, obs)
    assert again.lamps == model.lamps


def test_solve_theta_is_solves_theta(lamp_history, monkeypatch):
    """The alternation's ``solve_theta`` (issue 29) gives :meth:`FrameSolver.solve`'s θ bit for bit, at once and in
    chunks (each against ``solve`` in the same chunks: a matrix product's rounding may depend on its row count), with
    and without measured standard errors."""
    from illumon.model import solver as solver_mod

    obs, _, model = lamp_history
    y = np.asarray(obs.values) / model.noise["scale"]
    present = np.all(np.isfinite(y), axis=-1)
    solver = model.solver()
    for chunk in (8192, 7):
        monkeypatch.setattr(solver_mod, "SOLVE_CHUNK", chunk)
        for ev in (None, obs.extra_variance() / model.noise["scale"] ** 2):
            np.testing.assert_array_equal(solver.solve_theta(y, present, ev), solver.solve(y, present, ev)[0])


def test_joint_objective_glare_offsets_are_the_exact_joint_minimum(lamp_history, monkeypatch):
    """With each frame's glare offset on (``FLARE_SD``), the joint objective's reflectances and offsets
    (``_JointObjective._offsets``) are the joint minimum: the gradient of its quadratic in both is zero (the dense
    reflectance system after the offsets' block is eliminated, not an alternation), and the offsets follow the data
    (a glare added to one frame comes back as that frame's offset)."""
    from illumon.camera import formation
    from illumon.model.fit import _JointObjective, _normal_equations

    monkeypatch.setattr(formation, "FLARE_SD", 0.05)
    obs, _, model = lamp_history
    y = np.asarray(obs.values)[:12] / model.noise["scale"]
    present = np.all(np.isfinite(y), axis=-1)
    dm, rb = model.daylight_model(), model.reflectance_basis()
    theta = model.history_estimate[0].info["theta"][:12]
    glare = np.zeros_like(y)
    glare[3] = 0.04 * np.nanmean(y[3], axis=0)  # frame 3: 4 % of its mean added to every patch
    offsets = []
    for extra in (np.zeros_like(y), glare):
        obj = _JointObjective(y + extra, present, model.sensitivities, dm, rb, 0.02, 0.002)
        am, beta = obj._operators(theta)
        off, coef, _, prec = obj._offsets(beta, obj._weights(1.0)[1])
        np.testing.assert_allclose(prec, _normal_equations(am, obj._weights(1.0)[1], obj.lam, obj.mu)[0], rtol=1e-12)
        r = obj.yz - off[:, None, :] - np.einsum("fcj,pj->fpc", am, coef)
        grad_s = -np.einsum("fcj,fpc->pj", am, obj.w2 * r) + (coef - obj.mu) @ obj.lam
        u = obj.flare  # F × 3: o = u ⊙ φ
        phi = off / u
        grad_phi = -u * (obj.w2 * r).sum(axis=1) + phi
        scale = np.einsum("fcj,fpc->pj", am, obj.w2 * np.abs(obj.yz)).max()
        assert np.abs(grad_s).max() < 1e-8 * scale and np.abs(grad_phi).max() < 1e-8 * scale
        offsets.append(off)
    rise = (offsets[1][3] - offsets[0][3]) / glare[3, 0]
    others = np.abs(np.delete(offsets[1] - offsets[0], 3, axis=0)).max() / glare[3, 0].max()
    assert np.all((rise > 0.5) & (rise < 1.2)) and others < 0.2, (rise, others)


def test_mean_green_is_each_frames_np_mean_bit_for_bit():
    """The joint objective's start reads each frame's mean green over its present patches, the frames with the same
    number of patches at once: the values of ``np.mean`` frame by frame, to the last bit (1 where none is seen)."""
    from illumon.model.fit import _mean_green

    rng = np.random.default_rng(7)
    y = rng.lognormal(-1.0, 0.8, (400, 16, 3))
    present = rng.random((400, 16)) > rng.uniform(0.0, 0.6, (400, 1))
    present[:3] = False
    present[3, :] = True
    want = np.array([np.mean(y[f, present[f], 1]) if present[f].any() else 1.0 for f in range(len(y))])
    assert np.array_equal(_mean_green(y, present), want)
