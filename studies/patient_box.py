"""What share of patients a scene's stiffness box holds, judged by ratios and by absolute E, for stated populations.

    python -m studies patient-box [--scene fem_offline/scenes/patient_box.toml] [--n 200000] [--seed 0] [--publish]

Each population draws every tissue's E independently from a log-normal distribution (a median in kPa and the std of
ln E), from the shear-wave elastography the scene's `source` strings cite where there is one, and stated as an
assumption where there is none (the normal rectal wall, the bladder wall). A draw is inside the box by ratios when
one common factor puts every E_i / E_i,nominal inside its range (contracts.materials.ratio_shift_interval, what the
service judges), and by absolute E when every E is inside its range as it is. Tissues are drawn independently, which
is the pessimistic case for ratios: in a patient whose tissues all read soft (one scanner, one pressure), the common
factor absorbs it.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from studies import results

# tissue -> (median kPa, std of ln E, where from); the order of a scene's [materials]
POPULATIONS = {
    "benign gland": {
        "prostate": (35.0, 0.3, "between the benign means 27.9 and 42.3 kPa; 27.9 +- 7.9 kPa is a std of ln E of 0.28"),
        "rectal_wall": (60.0, 0.5,
                        "assumed: no normal-wall range found; the tumour cutoffs measured against it span 27-112 kPa"),
        "adipose": (8.3, 0.46, "9.24 +- 4.48 kPa (breast fat) as a log-normal: median 8.3, std of ln E 0.46"),
        "bladder": (100.38, 0.5, "assumed: the paper's E, no kPa range found"),
    },
    "cancer in the gland": {
        "prostate": (64.0, 0.3, "cancer medians and means 64.1 and 71.1 kPa"),
        "rectal_wall": (60.0, 0.5, "as above"), "adipose": (8.3, 0.46, "as above"),
        "bladder": (100.38, 0.5, "as above"),
    },
    "benign gland, twice the assumed spread": {
        "prostate": (35.0, 0.3, "as the benign gland"), "rectal_wall": (60.0, 1.0, "assumed, doubled"),
        "adipose": (8.3, 0.46, "as above"), "bladder": (100.38, 1.0, "assumed, doubled"),
    },
}


def shares(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[float, float]:
    """(share inside by ratios, share inside by absolute E) of theta = ln(E / E_nominal) draws (n, m)."""
    by_ratios = (theta - hi).max(axis=1) <= (theta - lo).min(axis=1)
    absolute = ((theta >= lo) & (theta <= hi)).all(axis=1)
    return float(by_ratios.mean()), float(absolute.mean())


def run(scene, *, n: int, seed: int, populations: dict = POPULATIONS) -> dict:
    """The shares of each population for a Scene's [materials] (fem_offline.scene)."""
    tissues = list(scene.materials)
    nominal = np.array([scene.tissues[t].youngs for t in tissues])
    lo, hi = (np.log(np.array([scene.materials[t].youngs_kpa_range[j] for t in tissues]) / nominal) for j in (0, 1))
    rng, rows = np.random.default_rng(seed), {}
    for name, pop in populations.items():
        median = np.array([pop[t][0] for t in tissues])
        spread = np.array([pop[t][1] for t in tissues])
        theta = np.log(median / nominal) + rng.normal(size=(n, len(tissues))) * spread
        ratios, absolute = shares(theta, lo, hi)
        rows[name] = {"by_ratios": ratios, "by_absolute_e": absolute,
                      "tissues": {t: {"median_kpa": pop[t][0], "std_ln_e": pop[t][1], "from": pop[t][2],
                                      "inside_alone": float(((theta[:, i] >= lo[i]) & (theta[:, i] <= hi[i])).mean())}
                                  for i, t in enumerate(tissues)}}
    return {"scene": scene.name, "n": n, "seed": seed, "tissues": tissues,
            "box_ratio_to_nominal": {t: [math.exp(lo[i]), math.exp(hi[i])] for i, t in enumerate(tissues)},
            "populations": rows}


def report(data: dict) -> str:
    lines = [f"# Patients inside the box of {data['scene']}", "",
             f"{data['n']:,} draws per population, tissues independent and log-normal.", "",
             "| population | inside by ratios | inside by absolute E | " + " | ".join(
                 f"{t.replace('_', ' ')}: median, std of ln E" for t in data["tissues"]) + " |",
             "|---|---|---|" + "---|" * len(data["tissues"])]
    for name, row in data["populations"].items():
        cells = [f"{row['tissues'][t]['median_kpa']:g} kPa, {row['tissues'][t]['std_ln_e']:g}" for t in data["tissues"]]
        lines.append(f"| {name} | {100 * row['by_ratios']:.0f} % | {100 * row['by_absolute_e']:.0f} % | "
                     + " | ".join(cells) + " |")
    first = next(iter(data["populations"].values()))
    lines += ["", "Where the medians and spreads come from: " + "; ".join(
        f"{t.replace('_', ' ')}: {v['from']}" for t, v in first["tissues"].items()) + "."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies patient-box", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=Path("fem_offline/scenes/patient_box.toml"))
    ap.add_argument("--n", type=int, default=200_000, help="draws per population (default 200,000)")
    ap.add_argument("--seed", type=int, default=0)
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    from fem_offline.scene import load_scene

    data = run(load_scene(args.scene), n=args.n, seed=args.seed)
    data["report_md"] = report(data)
    print(data["report_md"])
    print(f"wrote {results.write('patient_box', data, publish=args.publish)}")
    return 0
