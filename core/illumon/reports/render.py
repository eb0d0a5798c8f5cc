"""Rendering of the daylight report (:func:`illumon.reports.daylight.daylight_report`): PNG plots (matplotlib, Agg)
and the Markdown text, from the report's figures and summary."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..spectra import WAVELENGTHS

__all__ = ["plots", "markdown"]


def plots(out: Path, fig: dict, fits: dict, e: NDArray[np.float64], err: dict) -> list[str]:
    """Draw the report's PNG plots into ``out`` from its figures (matplotlib, Agg); the file names written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names: list[str] = []

    def save(figure: Any, name: str) -> None:
        figure.tight_layout()
        figure.savefig(out / name, dpi=110)
        plt.close(figure)
        names.append(name)

    _plot_error_vs_cct(plt, save, fig)
    _plot_delta_vs_cct(plt, save, fig)
    _plot_residual_by_wavelength(plt, save, fig)
    _plot_held_out_error_by_k(plt, save, fig)
    _plot_worst_fits(plt, save, fits, e, err)
    _plot_band_scan(plt, save, fig)
    _plot_gain_retrieval(plt, save, fig)
    return names


def _plot_error_vs_cct(plt: Any, save: Callable[[Any, str], None], fig: dict) -> None:
    """1 − GFC and relative RMSE of the CIE models against CCT."""
    f, ax = plt.subplots(1, 2, figsize=(11, 4))
    cct = np.asarray(fig["error_vs_cct"]["cct"])
    for k in ("cie_cct", "cie_xy", "cie_free", "theta"):
        ax[0].scatter(cct, 1 - np.asarray(fig["error_vs_cct"][f"gfc_{k}"]), s=3, label=k, alpha=0.5)
        ax[1].scatter(cct, fig["error_vs_cct"][f"rmse_{k}"], s=3, label=k, alpha=0.5)
    for a, lab in zip(ax, ("1 − GFC", "relative RMSE"), strict=True):
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel("CCT (K)")
        a.set_ylabel(lab)
        a.legend(markerscale=4, fontsize=8)
    ax[0].axhline(1e-3, color="k", lw=0.8, ls="--")
    save(f, "error_vs_cct.png")


def _plot_delta_vs_cct(plt: Any, save: Callable[[Any, str], None], fig: dict) -> None:
    """δ (offset from the CIE daylight locus) against CCT by sky state, with the measured prior's mean."""
    d = fig["delta_vs_cct"]
    f, ax = plt.subplots(figsize=(6, 4))
    sky = np.asarray(d["sky"])
    for c in sorted(set(sky)):
        s = sky == c
        ax.scatter(np.asarray(d["cct"])[s], np.asarray(d["delta_duv"])[s], s=3, label=c)
    ax.plot(1e6 / np.asarray(d["prior_mired"]), d["prior_delta"], "k-", label="measured prior δ̄")
    ax.axhline(0, color="grey", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("CCT (K)")
    ax.set_ylabel("δ = Duv − Duv(CIE daylight locus)")
    ax.legend(markerscale=4, fontsize=8)
    save(f, "delta_vs_cct.png")


def _plot_residual_by_wavelength(plt: Any, save: Callable[[Any, str], None], fig: dict) -> None:
    """RMS relative residual of each model by wavelength."""
    r = fig["residual_by_wavelength"]
    f, ax = plt.subplots(figsize=(7, 4))
    for k in ("cie_cct", "cie_xy", "cie_free", "theta", "cie_xy_failing"):
        ax.plot(r["wavelength_nm"], r[k], label=k)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("RMS relative residual")
    ax.legend(fontsize=8)
    save(f, "residual_by_wavelength.png")


def _plot_held_out_error_by_k(plt: Any, save: Callable[[Any, str], None], fig: dict) -> None:
    """Held-out and cross-validated error of the measured basis against the number of components."""
    h = fig["held_out_error_by_k"]
    f, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(h["k"], h["median_rmse"], "o-", label="held-out median")
    ax.semilogy(h["k"][: len(h["cv_error"])], h["cv_error"], "s--", label="training CV mean")
    ax.set_xlabel("principal components k")
    ax.set_ylabel("relative RMSE")
    ax.legend()
    save(f, "held_out_error_by_k.png")


def _plot_worst_fits(plt: Any, save: Callable[[Any, str], None], fits: dict, e: NDArray[np.float64], err: dict) -> None:
    """The four spectra CIE D fits worst, with their fits."""
    worst = np.argsort(err["cie_xy"]["gfc"])[:4]
    f, axs = plt.subplots(1, 4, figsize=(14, 3.5))
    for a, i in zip(axs, worst, strict=False):
        a.plot(WAVELENGTHS, e[i], "k", label="measured")
        a.plot(WAVELENGTHS, fits["cie_xy"][i], label="CIE D (own xy)")
        a.plot(WAVELENGTHS, fits["cie_free"][i], label="S0/S1/S2 free")
        a.set_title(f"#{i}: GFC {err['cie_xy']['gfc'][i]:.4f}", fontsize=9)
        a.set_xlabel("nm")
    axs[0].legend(fontsize=7)
    save(f, "worst_fits.png")


def _plot_band_scan(plt: Any, save: Callable[[Any, str], None], fig: dict) -> None:
    """The absorption-band scan's evidence by band centre."""
    b = fig["band_scan"]
    f, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(b["centre_nm"], b["evidence"])
    ax.set_xlabel("band centre (nm)")
    ax.set_ylabel("summed matched-filter evidence")
    save(f, "band_scan.png")


def _plot_gain_retrieval(plt: Any, save: Callable[[Any, str], None], fig: dict) -> None:
    """Median angular error per simulated history, CIE D against measured (when the retrievals ran)."""
    g = fig["gain"].get("retrieval_per_history")
    if g:
        f, ax = plt.subplots(figsize=(5, 4))
        ax.boxplot([[x["median_angular_cie"] for x in g], [x["median_angular_measured"] for x in g]])
        ax.set_xticks([1, 2], ["CIE D", "measured"])
        ax.set_ylabel("median angular error per history (°)")
        save(f, "gain_retrieval.png")


def _fmt(x: float | None, p: int = 4) -> str:
    return "—" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{p}g}"


def markdown(s: dict) -> str:
    """The report's Markdown text from its summary, section by section."""
    lines = _md_fits(s)
    lines += _md_cause(s["cause"])
    lines += _md_extension(s["extension"], s["held_out"], s["gain"])
    lines += _md_gain(s["gain"])
    lines += _md_detection(s["detection"])
    lines += ["", "![band scan](band_scan.png)", "", f"Report written in {s['seconds']:.1f} s.", ""]
    return "\n".join(lines)


def _md_fits(s: dict) -> list[str]:
    """The title, the input and section 1: how well the product's daylight models fit (overall, by CCT, band, sky)."""
    m = s["models"]
    lines = [
        "# Daylight report",
        "",
        f"Input: `{s['input']['path']}` — {s['input']['n_spectra']} spectra used "
        f"({s['input']['n_dropped_nonpositive']} dropped as non-positive); CCT 5/50/95 %: "
        + ", ".join(f"{x:.0f} K" for x in s["input"]["cct_percentiles_5_50_95"]) + ".",
        "",
        "## 1. How well the product's daylight models fit",
        "",
        "| model | median rel. RMSE | 95 % rel. RMSE | median GFC | GFC ≥ 0.999 | GFC ≥ 0.9999 |",
        "|---|---|---|---|---|---|",
    ]
    for k, v in m.items():
        lines.append(f"| {k} | {v['median_rmse']:.4f} | {v['p95_rmse']:.4f} | {v['median_gfc']:.5f} | "
                     f"{v['frac_gfc_999']:.1%} | {v['frac_gfc_9999']:.1%} |")
    lines += ["", "By CCT (CIE D at own xy):", "", "| CCT (K) | n | median δ | median RMSE cie_xy | GFC ≥ 0.999 cie_xy |",
              "|---|---|---|---|---|"]
    for r in s["by_cct"]:
        hi = f"{r['cct_to']:.0f}" if r["cct_to"] else "∞"
        lines.append(f"| {r['cct_from']:.0f}–{hi} | {r['n']} | {r['median_delta_duv']:+.4f} | "
                     f"{r['median_rmse_cie_xy']:.4f} | {r['frac_gfc_999_cie_xy']:.1%} |")
    lines += ["", "RMS relative residual by wavelength band:", "",
              "| band (nm) | " + " | ".join(k for k in m) + " |", "|---" * (len(m) + 1) + "|"]
    for r in s["by_band"]:
        lines.append(f"| {r['band']} | " + " | ".join(f"{r[k]:.4f}" for k in m) + " |")
    lines += ["", "By sky state (classified from CCT and δ, see `sky_class`):", "",
              "| sky | n | median CCT | median δ | median RMSE cie_xy | GFC ≥ 0.999 cie_xy |", "|---|---|---|---|---|---|"]
    for r in s["by_sky"]:
        lines.append(f"| {r['sky']} | {r['n']} | {r['median_cct']:.0f} | {r['median_delta_duv']:+.4f} | "
                     f"{r['median_rmse_cie_xy']:.4f} | {r['frac_gfc_999_cie_xy']:.1%} |")
    lines += [
        "",
        "![error vs CCT](error_vs_cct.png) ![delta vs CCT](delta_vs_cct.png)",
        "![residual by wavelength](residual_by_wavelength.png) ![worst fits](worst_fits.png)",
    ]
    return lines


def _md_cause(c: dict) -> list[str]:
    """Section 2: where and why CIE D fails."""
    lines = [
        "",
        "## 2. The cause",
        "",
        f"- {c['frac_fail_cie_xy']:.1%} of spectra ({c['n_fail_cie_xy']}) have GFC < 0.999 even with CIE D at their "
        f"own chromaticity. Failing spectra have median CCT {_fmt(c['median_cct_fail'], 5)} K vs "
        f"{_fmt(c['median_cct_pass'], 5)} K for the rest; the failure rate is {_fmt(c['frac_fail_above_8000K'], 3)} "
        f"above 8000 K and {_fmt(c['frac_fail_below_6200K'], 3)} below 6200 K.",
        f"- Off the locus: {c['frac_off_locus_003']:.1%} of spectra lie more than 0.003 Duv from the CIE daylight "
        f"locus; median |δ| is {_fmt(c['median_abs_delta_fail'], 3)} for failing vs "
        f"{_fmt(c['median_abs_delta_pass'], 3)} for passing spectra (correlation of log RMSE with |δ|: "
        f"{c['correlations']['rmse_vs_abs_delta']:+.2f}, with mired: {c['correlations']['rmse_vs_mired']:+.2f}). "
        "Putting the spectrum on the locus at its CCT (cie_cct) raises the median RMSE from "
        f"{c['cie_cct_vs_cie_xy_median_rmse'][1]:.4f} to {c['cie_cct_vs_cie_xy_median_rmse'][0]:.4f}.",
        f"- Where: the residual concentrates in {c['worst_band']} nm; for failing spectra it peaks at "
        f"{c['peak_residual_nm_fail']:.0f} nm, next to the {c['peak_feature']}.",
        "- Why, physically: the CIE D basis (Judd et al. 1964) averages skies into one spectrum per chromaticity. "
        "Light from blue sky without direct sun is Rayleigh-scattered: high CCT and above the locus, with a "
        "short-wave shape that S1/S2 cannot follow; direct-sun and low-sun spectra pass through long air paths whose "
        "absorption (ozone Chappuis band around 600 nm, O2 and H2O bands towards 700 nm) and aerosol extinction vary "
        "with the day, not with chromaticity; the 5-nm smoothed Fraunhofer lines differ with instrument resolution.",
    ]
    return lines


def _md_extension(ex: dict, ho: dict, g: dict) -> list[str]:
    """Section 3: the measured-daylight basis fitted on the training half and its held-out errors."""
    lines = [
        "",
        "## 3. Extended model: measured-daylight basis with an off-locus parameter",
        "",
        f"PCA on the training half ({ex['n_train']} spectra; split: **{g['split']}**"
        + (", file order, first half trains" if g["split"] == "time" else f", random halves, seed {g['seed']}")
        + f"); k = **{ex['n_components']}** components chosen by 5-fold cross-validation within the training half. "
        f"Off-locus prior δ̄(mired) = {ex['delta_prior']['coef'][0]:+.5f} {ex['delta_prior']['coef'][1]:+.2e}·mired, "
        f"σ_δ = {ex['delta_prior']['sd']:.5f}. Solver: `--daylight-model measured`.",
        "",
        f"Held-out spectra ({ex['n_held_out']}, never used to build the basis):",
        "",
        "| model | median rel. RMSE | median GFC | GFC ≥ 0.999 | GFC ≥ 0.9999 |",
        "|---|---|---|---|---|",
    ]
    for k, v in ho.items():
        lines.append(f"| {k} | {v['median_rmse']:.4f} | {v['median_gfc']:.5f} | {v['frac_gfc_999']:.1%} | "
                     f"{v['frac_gfc_9999']:.1%} |")
    lines += ["", "Held-out median RMSE by k: " + ", ".join(f"{i + 1}: {x:.4f}"
                                                         for i, x in enumerate(ex["held_out_median_rmse_by_k"])),
              "", "![held-out error by k](held_out_error_by_k.png)", ""]
    return lines


def _md_gain(g: dict) -> list[str]:
    """Section 4: the gain in camera whites and simulated retrievals (or why it was skipped)."""
    lines = ["## 4. Gain where it matters", ""]
    if "skipped" in g:
        lines.append(g["skipped"])
    else:
        cw = g["camera_white_at_true_chromaticity"]
        lines.append(
            f"Camera white predicted at the true chromaticity ({g['camera_white_n']} held-out spectrum × camera pairs): "
            f"median angular error CIE D {cw['cie']['median_deg']:.3f}° → measured {cw['measured']['median_deg']:.3f}° "
            f"(95 %: {cw['cie']['p95_deg']:.3f}° → {cw['measured']['p95_deg']:.3f}°)."
        )
        rt = g.get("retrieval")
        if rt:
            a, b = rt["cie"], rt["measured"]
            lines += [
                "",
                f"Joint retrieval on {rt['n_histories']} simulated histories ({rt['n_frames']} frames of held-out "
                f"daylight, {rt['n_patches']} random measured reflectances, random measured camera, "
                f"{rt['seconds']:.0f} s):",
                "",
                "| daylight model | median angular error (°) | mean angular error (°) | median spectral RMSE | median GFC |",
                "|---|---|---|---|---|",
                f"| cie | {a['median_angular_deg']:.3f} | {a['mean_angular_deg']:.3f} | {a['median_spectral_rmse']:.4f} | "
                f"{a['median_gfc']:.5f} |",
                f"| measured | {b['median_angular_deg']:.3f} | {b['mean_angular_deg']:.3f} | "
                f"{b['median_spectral_rmse']:.4f} | {b['median_gfc']:.5f} |",
                "",
                f"Change of the median angular error: {b['median_angular_deg'] - a['median_angular_deg']:+.3f}°.",
                "",
                "![gain](gain_retrieval.png)",
            ]
    return lines


def _md_detection(det: dict) -> list[str]:
    """The hidden-distortion search: an absorption band and an off-locus tint."""
    bd, td = det["band"], det["tint"]
    lines = ["", "## Hidden distortions (residual analysis against the measured model)", ""]
    lines.append(
        f"- Absorption band: **found** at {bd['centre_nm']:.0f} nm (FWHM ≈ {bd['fwhm_nm']:.0f} nm, median depth "
        f"{bd['depth_median']:.3f}) in {bd['n_affected']} spectra; nearest known feature: {bd['feature']}."
        if bd["found"] else "- Absorption band: none beyond the measured model's natural residual."
    )
    lines.append(
        f"- Off-locus tint: **found**, shift {td['shift_duv']:+.4f} Duv in {td['n_affected']} spectra "
        f"(cluster separation {td['separation']:.1f} σ)."
        if td["found"] else f"- Off-locus tint: none (best two-cluster separation {td['separation']:.1f} σ)."
    )
    return lines
