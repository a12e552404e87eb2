#!/usr/bin/env bash
# Makes a model fitted to the shipped rooms, data/spar_rooms_fitted.spar (training/
# README.md, "A model fitted to the shipped rooms"; not shipped: on this CPU the recipe stays
# below the general model there): trains on other takes of those rooms (never their frames;
# seed fixed; about 80 minutes on two cores), measures it with `spar eval` on the shipped
# scenes, and packs it with a model card saying what it is.
#
#   bash training/fit-rooms.sh [RUN_DIR]       (default runs/fit-rooms; needs the build)
set -euo pipefail
cd "$(dirname "$0")/.."
run=${1:-runs/fit-rooms}
scenes=data/scenes
pool=400
spar=${SPAR_BUILD:-build}/bin/spar
[ -x "$spar" ] || { echo "fit-rooms: $spar not built (bash scripts/setup/build.sh)" >&2; exit 1; }
training/spar-train --out "$run" --fit-scenes "$scenes" --scenes $pool --steps 2200 --lr 6e-4 --seed 0 \
  --eval-scenes "$scenes" --eval-every 275
"$spar" eval --model "$run/model.spar" --scenes "$scenes" --out "$run/eval_shipped.json" --redo
PYTHONPATH=training /usr/bin/python3 -m spar_train.fitted_card "$run/curve.jsonl" "$run/eval_shipped.json" \
  "$scenes" $pool > "$run/card.json"
converter/spar-convert "$run/model.spar" --model-card "$run/card.json" -o data/spar_rooms_fitted.spar
echo "fit-rooms: wrote data/spar_rooms_fitted.spar ($(cat "$run/card.json" | tr -d '\n' | cut -c1-200)...)"
