"""The dead-cell probability's calibration, measured on the validation cities, and fitted on maps the predictor never saw.

Per validation city, the predictor's scores (``rl.predictor.scores_of``: median and p90 |error|, dead/live agreement,
expected calibration error, ms per map) as it is; with Platt scaling of its dead-cell logit
(``rl.predictor.learned.pack_calibration``, what ``uavrl calibrate-predictor`` fits) on the users of training-maps packs
(``--maps``: cities the predictor was not trained on, never a validation or test city); and with Platt scaling fitted
on the other validation cities (leave one city out: the city scored is never one it was fitted on). The reliability
diagrams of all three in one figure (``--figure``).

    python experiments/calibration.py [--predictor data/agents/searcher/unet] [--maps data/trainmaps] [--packs 'tt-*']
        [--figure docs/img/reliability.png] [--city etoile-val ...]
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from common import VALIDATION, validation_parser

from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.trainmaps import read_pack, select_packs
from uavplace.infra.console import markdown_table
from uavplace.rl.config import DEFAULT_PREDICTOR
from uavplace.rl.predictor import load_predictor, platt_scaling, predicted_and_measured, reliability, scores_of
from uavplace.rl.predictor.learned import pack_calibration


def logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, np.float64), 1e-7, 1 - 1e-7)
    return np.log(p) - np.log1p(-p)


def main() -> None:
    ap = validation_parser(__doc__, episodes=0)
    ap.add_argument("--predictor", type=Path, default=DEFAULT_PREDICTOR)
    ap.add_argument("--maps", type=Path, default=Path("data/trainmaps"), help="Training-maps packs to fit the scaling on")
    ap.add_argument(
        "--packs",
        action="append",
        default=[],
        help="Only the packs whose city's name matches this pattern (tt-*: the tiered ones)",
    )
    ap.add_argument("--figure", type=Path, default=None, help="Write the reliability diagrams here (PNG)")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    predictor = load_predictor(args.predictor)
    t0 = time.perf_counter()
    packs = [read_pack(p) for p in select_packs([args.maps], args.packs)]
    scale, bias = pack_calibration(predictor, packs)  # what `uavrl calibrate-predictor` fits
    print(f"Platt scaling on {sum(len(m.users) for m in packs)} users of the packs {args.packs or '*'} in {args.maps}: scale "
          f"{scale:.3f}, bias {bias:+.3f} ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    rows = [["city", "predictor", "median |error| [dB]", "p90 |error| [dB]", "dead/live agreement", "calibration error"]]
    diagrams = {}
    cities = args.city or list(VALIDATION)
    measured = {}
    for city in cities:
        bundle = load_bundle(city, root=args.root)
        if bundle.manifest.config.role == "test":
            ap.error(f"{city} is a test city: nothing is learnt from it")
        measured[city] = predicted_and_measured(bundle, bundle.user_indices(), predictor)

    def scaled(pm: dict, a: float, b: float) -> dict:
        return dict(pm, p_dead=1 / (1 + np.exp(-(a * logit(pm["p_dead"]) + b))))

    for city in cities:
        pm = measured[city]
        others = [c for c in cities if c != city]
        loo = platt_scaling(np.concatenate([logit(measured[c]["p_dead"]) for c in others]),
                            np.concatenate([measured[c]["low"] for c in others])) if others else (1.0, 0.0)  # fmt: skip
        print(f"{city}: Platt scaling on the other validation cities: scale {loo[0]:.3f}, bias {loo[1]:+.3f}")
        variants = (("as shipped", pm), ("calibrated on the packs", scaled(pm, scale, bias)),
                    ("calibrated on the other validation cities", scaled(pm, *loo)))  # fmt: skip
        for name, m in variants:
            s = scores_of(m)
            rows.append([city, name, f"{s['median_error_db']:.1f}", f"{s['p90_error_db']:.1f}",
                         f"{100 * s['dead_live_agreement']:.1f} %", f"{s['calibration_error']:.3f}"])  # fmt: skip
            diagrams[(city, name)] = reliability(m["p_dead"], m["low"])[1]
    print(markdown_table(rows))
    if args.figure is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, len(cities), figsize=(3.2 * len(cities), 3.4), squeeze=False, sharey=True)
        for ax, city in zip(axes[0], cities, strict=True):
            ax.plot([0, 1], [0, 1], color="grey", linewidth=0.8, linestyle=":")
            styles = (("as shipped", "o-"), ("calibrated on the packs", "s--"),
                      ("calibrated on the other validation cities", "^-."))  # fmt: skip
            for name, style in styles:
                d = np.array(diagrams[(city, name)])
                ax.plot(d[:, 0], d[:, 1], style, markersize=4, label=name)
            ax.set_title(city, fontsize=9)
            ax.set_xlabel("predicted dead probability", fontsize=8)
            ax.tick_params(labelsize=7)
        axes[0][0].set_ylabel("observed frequency (dead or at the floor)", fontsize=8)
        axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(args.figure, dpi=100)
        print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()
