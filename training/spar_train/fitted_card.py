"""The model card of a model fitted to a folder of scenes (training/fit-rooms.sh): what it was
fitted to, its steps and minutes (the run's curve.jsonl), and what `spar eval` measured on
those scenes at K = 3 against copying the nearest input (its result.json). The card goes into
the packed file (spar-convert --model-card), so `spar render` and its page say what the model
is before anyone judges the engine by its views.

    python3 -m spar_train.fitted_card RUN/curve.jsonl EVAL.json SCENES_DIR POOL_SIZE > CARD.json
"""
import json
import sys

from .fit import fit_seeds


def fitted_card(curve_path: str, eval_path: str, scenes_dir: str, pool_size: int) -> dict:
    with open(curve_path) as f:
        last = [json.loads(line) for line in f if line.strip()][-1]
    with open(eval_path) as f:
        k3 = json.load(f)["results"]["3"]
    seeds = fit_seeds(scenes_dir)
    rooms = "%d rooms" % len(seeds) if len(seeds) != 1 else "1 room"
    return {
        "kind": "demonstration",
        "about": "fitted to the %s of the shipped scenes (seeds %s) on other camera paths and other "
                 "moments of their movers, never their own frames, it renders those rooms and no others"
                 % (rooms, ", ".join(str(s) for s in seeds)),
        "measured": {"what": "the shipped scenes' K=3", "psnr_db": round(k3["psnr"], 2),
                     "baseline": "copying the nearest input",
                     "baseline_psnr_db": round(k3["psnr_nearest_input"], 2)},
        "training": {"data": "%d takes of the %s of %s (spar_scenes takes 1 and up)" % (pool_size, rooms, scenes_dir),
                     "steps": int(last["step"]), "minutes": round(float(last["minutes"]), 1)},
    }


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 4:
        print("usage: python3 -m spar_train.fitted_card CURVE.jsonl EVAL.json SCENES_DIR POOL_SIZE", file=sys.stderr)
        return 2
    json.dump(fitted_card(argv[0], argv[1], argv[2], int(argv[3])), sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
