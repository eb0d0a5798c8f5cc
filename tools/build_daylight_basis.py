"""Derive the measured-daylight model shipped in ``core/illumon/data`` from the Granada daylight spectra.

Run: ``python tools/build_daylight_basis.py [--split time|random]``. Reads ``../shared/data/daylight/granada_2600.csv``
(Hernández-Andrés, Romero, Nieves & Lee, "Color and spectral analysis of daylight in southern Europe", JOSA A 18(6),
1325–1335, 2001; 2600 global-irradiance spectra, Granada, two years, all sky states; as distributed in the
``neuralsignal/dreye`` repository), keeps the *training* half only (default: the first 1300 spectra in file order,
a split by time; the second half is held out for evaluation by ``illumon report daylight``) and writes

* ``measured_daylight_basis.csv`` — mean and principal components of unit-mean spectra on 400–700 nm / 5 nm;
* ``measured_daylight_model.json`` — regression on chromaticity, residual shape prior, off-locus prior, provenance.

See :mod:`illumon.daylight.measured` for the model.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from illumon.daylight.measured import fit_measured_daylight, split_indices
from illumon.simulation import datasets

OUT = Path(__file__).resolve().parents[1] / "core" / "illumon" / "data"
SOURCE = (
    "Hernández-Andrés J, Romero J, Nieves JL, Lee RL Jr, 'Color and spectral analysis of daylight in southern Europe', "
    "JOSA A 18(6):1325-1335 (2001); Granada global irradiance, 2600 spectra 300-1100 nm at 5 nm; "
    "file as distributed in github.com/neuralsignal/dreye"
)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=("time", "random"), default="time")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    ids, spectra = datasets.load_granada_daylight()
    train, test = split_indices(len(ids), args.split, args.seed)
    prov = {
        "source": SOURCE,
        "file": "shared/data/daylight/granada_2600.csv",
        "split": args.split,
        "seed": args.seed,
        "training_ids": f"{ids[train[0]]}..{ids[train[-1]]}" if args.split == "time" else "random half",
        "n_training_spectra": int(train.size),
        "n_held_out_spectra": int(test.size),
        "normalisation": "each spectrum scaled to unit mean over 400-700 nm",
        "builder": "tools/build_daylight_basis.py",
        "licence_note": "derived from published measurements; research use, cite the source paper",
    }
    data = fit_measured_daylight(spectra[train], provenance=prov)
    data.save(
        str(OUT / "measured_daylight_basis.csv"),
        str(OUT / "measured_daylight_model.json"),
        comments=(
            f"illumon measured-daylight basis: mean + {data.k} principal components of unit-mean spectra",
            f"built by tools/build_daylight_basis.py from the {args.split}-split training half ({train.size} spectra) of",
            "Granada daylight (Hernandez-Andres et al., JOSA A 18(6), 2001; via neuralsignal/dreye)",
            "model parameters and provenance: measured_daylight_model.json",
        ),
    )
    print(f"k = {data.k} (cv errors {', '.join(f'{e:.5f}' for e in data.cv_errors)}), delta sd {data.delta_sd:.5f}")


if __name__ == "__main__":
    main()
