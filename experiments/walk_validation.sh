#!/usr/bin/env bash
# The walk's reach on the validation cities (issue 51): each city traced once, filled with the 4-neighbour and the
# Euclidean walk, both built, and the shipped agents played on the same episodes of both (experiments/twin_city.py).
# The decision it informs: re-trace the embedded corpus with the new walk only if the numbers move.
# Resumable: the traces are kept in runs/traces (TRACES), a city whose table exists is skipped.
# About 25 minutes of tracing on the 2-core machine, then 500 episodes a city.
#
#     bash experiments/walk_validation.sh [CITY ...]      (default: the five validation cities)
set -euo pipefail
traces=${TRACES:-runs/traces}
out=runs/walk
declare -A source=(
    [corpus-016]="procedural:mixed --seed 116 --users 16"
    [corpus-017]="procedural:mixed --seed 117 --users 16"
    [oldtown-005]="procedural:oldtown --seed 205 --users 16"
    [etoile-val]="sionna:etoile --crop=200,-200,400,200 --users 16 --seed 6"
    [florence-val]="sionna:florence --crop=200,-250,494,250 --users 16 --seed 7"
)
cities=("$@")
[ ${#cities[@]} -gt 0 ] || cities=(corpus-016 corpus-017 oldtown-005 etoile-val florence-val)
for city in "${cities[@]}"; do
    [ -e "$out/$city.csv" ] && { echo "$city: done ($out/$city.csv)"; continue; }
    for walk in 4-neighbour euclidean; do
        # shellcheck disable=SC2086
        uavdata simulate ${source[$city]} --name "$city" --samples 1.6e7 --gap-fill-walk "$walk" \
            --out "$out/$walk" --trace-cache "$traces" --quiet
    done
    uavdata ingest "$out/4-neighbour/$city/" --name "$city-w4" --out "$out/processed" --quiet
    uavdata ingest "$out/euclidean/$city/" --name "$city-we" --out "$out/processed" --quiet
    uavdata build --city "$city-w4" --city "$city-we" --grid 4m --alt 10 --root "$out/processed" --quiet
    python experiments/twin_city.py --paths "$city-we" --radio-map "$city-w4" --labels euclidean,4-neighbour \
        --episodes 500 --root "$out/processed" --csv "$out/$city.csv.part" | tee "$out/$city.txt"
    mv "$out/$city.csv.part" "$out/$city.csv"
done
# Every city in one table (docs/fidelity.md, "The walk's reach").
tables=("${cities[@]/#/$out/}")
python experiments/twin_city.py --summary "${tables[@]/%/.csv}" --labels euclidean,4-neighbour
