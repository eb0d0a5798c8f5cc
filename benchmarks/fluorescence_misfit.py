"""Why a clean development history reads as fluorescent: the fluorescence ratio of its best patch on the measured
values, on the simulator's exact values, with the surfaces and lights put inside the spectral model's bases, and with
the reflectance prior weakened.

Run: ``python benchmarks/fluorescence_misfit.py SIM SEED CAMERA`` (``SIM`` ``rawsim`` or ``imgsim``, a clean
development history: ``SEED`` 3 000…, ``CAMERA`` the one :mod:`benchmarks.diagnose` ``--split dev`` gives it, e.g.
``rawsim 3002 Nikon_D300s``, ``imgsim 3005 Nikon_D40``). Prints, per variant, the ratio
:func:`illumon.diagnosis.stages.spectral_stage` compared with ``NONE_MARGIN["fluorescence"]`` before issue 28's
branch ``diag-clean`` (best patch's in-sample gain over the runner-up's under the Gaussian reflectance prior, at least
the median of χ²₃; the stage's weights without the measured standard errors), the two patches and the best patch's
emission share, and each surface's squared Mahalanobis distance under the reflectance prior (the coefficients of its
projection on the basis); then the ratio the stage compares now on the observed values
(:func:`illumon.diagnosis.spectral.studentised_fluorescence_ratio` with the Student-t prior and the emission above its
excitation band, :data:`illumon.diagnosis.spectral.STOKES_SHIFT_NM`). Variants:

* ``observed``: the history's values;
* ``exact``: ``Σλ E_f R_p C`` at the history's exposure (no noise, no pipeline);
* ``in span``: the same with every surface projected on the reflectance basis and every light on the measured-daylight
  basis (no basis misfit left);
* ``prior / 10``: the observed values, the reflectance prior's precision (and the local departures' ``1/sd²``) divided
  by 10 in the fluorescence test.
"""

from __future__ import annotations

import sys
import warnings

import imgsim
import numpy as np
import rawsim
from illumon.diagnosis import spectral, stages
from illumon.diagnosis.noise import dark_level_set, history_dark_level
from illumon.observations import Observations
from illumon.priors import default_daylight_prior, reflectance_basis
from numpy.typing import NDArray
from scipy.stats import chi2


def ratio(obs: Observations, values: NDArray[np.float64], css: NDArray[np.float64], prior_factor: float = 1.0) -> str:
    """The fluorescence ratio of ``values`` (frames and patches of ``obs``) and its patches, as one line."""
    o = Observations(list(obs.frames), list(obs.patches), values, list(obs.times), None)
    with dark_level_set(history_dark_level(values, None)):
        base = stages.refined_spectral_base(o, css)
        lam = base.prob.Lambda
        base.prob.Lambda = lam * prior_factor
        try:
            fg, _, share = spectral.generic_fluorescence_gains(
                base, local_sd=spectral.LOCAL_REFLECTANCE_SD / np.sqrt(prior_factor), prior_dof=None, shift_nm=None)
        finally:
            base.prob.Lambda = lam
    p, q = np.argsort(-fg)[:2]
    r = fg[p] / max(fg[q], chi2.median(3))
    return f"ratio {r:5.2f}  best patch {p} (gain {fg[p]:.1f}), runner-up {q} ({fg[q]:.1f}), emission share {share[p].round(3)}"


def main() -> int:
    warnings.filterwarnings("ignore")
    if len(sys.argv) != 4 or sys.argv[1] not in ("rawsim", "imgsim"):
        print(__doc__, file=sys.stderr)
        return 2
    sim, seed, camera = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    if sim == "rawsim":
        h = rawsim.hide_effect_raw("none", camera, seed, split="dev")
        refl, light = h.history.reflectances, h.history.illuminants
    else:
        h = imgsim.hide_effect_img("none", camera, seed, split="dev")
        refl, light = h.reflectances, h.illuminants
    obs, css = h.observations, np.asarray(h.sensitivities, dtype=float)
    exposure = h.true_white / (light @ css)  # F × 3

    def render(r: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.einsum("fl,pl,lc->fpc", e, r, css) * exposure[:, None, :]

    rb = reflectance_basis()
    coef = np.linalg.lstsq(rb.functions, refl.T, rcond=None)[0]
    d = coef.T - rb.prior_mean
    maha = np.einsum("pi,ij,pj->p", d, np.linalg.inv(rb.prior_covariance), d)
    dp = default_daylight_prior()
    day = np.column_stack([dp.mean, dp.components])
    light_in = (day @ np.linalg.lstsq(day, light.T, rcond=None)[0]).T
    print(f"{sim} clean seed {seed} ({camera}): {obs.values.shape[0]} frames, {obs.values.shape[1]} patches")
    print(f"surfaces' squared Mahalanobis distance under the reflectance prior: {maha.round(1)}")
    print(f"observed    {ratio(obs, obs.values, css)}")
    print(f"exact       {ratio(obs, render(refl, light), css)}")
    print(f"in span     {ratio(obs, render((rb.functions @ coef).T, light_in), css)}")
    print(f"prior / 10  {ratio(obs, obs.values, css, 0.1)}")
    with dark_level_set(history_dark_level(obs.values, None)):
        base = stages.refined_spectral_base(obs, css)
        r, p, _, scale = spectral.studentised_fluorescence_ratio(base, spectral.generic_fluorescence_gains(base)[0],
                                                                 float(chi2.median(3)), stages.REFINE_ITERS)
    print(f"now         studentised ratio {r:5.2f}  best patch {p}, scale {scale:.1f} (Student-t prior, emission above "
          f"its band)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
