#!/usr/bin/env bash
# The learned predictor's training maps at scale (docs/searcher.md, "Training maps"): COUNT procedural training cities
# of the six mixed styles (tm-000, tm-001, ...; seeds 1000, 1001, ...; 25 users each), ray-traced like the embedded
# corpus (1.6e7 rays per user, the 4-neighbour walk), ingested and built under runs/trainmaps/processed, and packed
# into data/trainmaps/<city>.npz (dataset/trainmaps.py: SINR to 0.5 dB, provenance, about 7 kB a user).
# No validation, test or reserved city is among them: names tm-* (seeds from 1000) or NAME-* (SEED on; tt: 3000), never
# the corpus's seeds (100-123).
#
# Resumable at every stage: a city traced with the same settings is skipped, an identical bundle is not rebuilt and a
# pack of the same bundle version is left alone, so run it again after a stop. About 220 s a city (8.7 s a user) on the
# 2-core machine; the cities are Ray tasks (RAY_ADDRESS=ray://head:10001 for a cluster; one city a task).
#
#     COUNT=200 bash experiments/training_maps.sh          # trace, then pack every traced city
#     FIRST=42 COUNT=200 bash experiments/training_maps.sh # continue after the packed tm-000..041 on a fresh clone
#     PACK_ONLY=1 bash experiments/training_maps.sh        # pack the cities traced so far (while a trace runs)
#     STYLE=tiered NAME=tt SEED=3000 COUNT=60 bash experiments/training_maps.sh  # another style: tt-000, ... seeds 3000, ...
#     uavrl train-predictor --maps data/trainmaps ...      # then (docs/searcher.md)
set -euo pipefail
count=${COUNT:-200}
style=${STYLE:-mixed}
name=${NAME:-tm}
seed=${SEED:-1000}
raw=runs/trainmaps/raw
root=runs/trainmaps/processed
out=${OUT:-data/trainmaps}
if [ -z "${PACK_ONLY:-}" ]; then
    uavdata simulate "procedural:$style" --count "$count" --first "${FIRST:-0}" --name "$name" --seed "$seed" --users 25 --samples 1.6e7 \
        --gap-fill-walk 4-neighbour --out "$raw" --trace-cache runs/traces ${RAY_ADDRESS:+--ray-address "$RAY_ADDRESS"}
fi
cities=()
for folder in "$raw"/"$name"-*/; do
    [ -f "$folder/simulation.json" ] || continue  # a city still being traced has none yet
    city=$(basename "$folder")
    uavdata ingest "$folder" --out "$root" --quiet
    cities+=("$city")
done
[ ${#cities[@]} -gt 0 ] || { echo "no traced city under $raw yet"; exit 0; }
uavdata build --grid 4m --alt 10 --root "$root" --quiet "${cities[@]/#/--city=}"
uavdata pack "${cities[@]}" --root "$root" --raw "$raw" --out "$out"
