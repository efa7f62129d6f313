#!/usr/bin/env bash
# Ray-trace every embedded city of data/raw/ (the README's data section), into OUT (default data/raw).
# Resumable: a city whose simulation.json records the same settings is skipped, so run it again after a stop.
# The traced maps are kept in runs/traces (TRACES): changing only the fill's reach, decay or walk re-fills in seconds.
# The embedded cities keep the 4-neighbour walk they were made with: the Euclidean walk (the default since) did not
# move the validation cities' numbers (docs/fidelity.md, "The walk's reach").
# About 90 minutes on the 2-core machine alone (fine radio maps at 1.6e7 rays per user, then the direct paths).
#
#     bash experiments/embedded_data.sh [OUT]
#
# To replace committed cities with a re-trace that records provenance: trace into runs/retrace, then
#     python experiments/retrace_compare.py --city test --install   # what moved, then the swap
set -euo pipefail
out=${1:-data/raw}
traces=${TRACES:-runs/traces}
common=(--samples 1.6e7 --gap-fill-walk 4-neighbour --out "$out" --trace-cache "$traces")
uavdata simulate procedural:mixed --count 18 --name corpus --seed 100 --users 16 "${common[@]}"
uavdata simulate procedural:oldtown --count 6 --name oldtown --seed 200 --users 16 "${common[@]}"
uavdata simulate procedural:test --name test --users 25 --seed 2 "${common[@]}"
uavdata simulate sionna:etoile --crop=-200,-200,200,200 --name etoile --users 25 --seed 4 "${common[@]}"
uavdata simulate sionna:florence --crop=-200,-250,200,250 --name florence --users 25 --seed 5 "${common[@]}"
# Validation crops of the two real scenes, beside (never overlapping) their test crops above: decisions on real geometry.
uavdata simulate sionna:etoile --crop=200,-200,400,200 --name etoile-val --users 16 --seed 6 "${common[@]}"
uavdata simulate sionna:florence --crop=200,-250,494,250 --name florence-val --users 16 --seed 7 "${common[@]}"
uavdata simulate procedural:train --name train --users 27 --seed 1 "${common[@]}"
uavdata simulate procedural:tiny --name tiny --users 4 --seed 3 --samples 2e6 --gap-fill-walk 4-neighbour --out "$out" --trace-cache "$traces"
uavdata simulate procedural:tiny --name tiny-routes --users 4 --seed 3 --samples 2e6 --routes 4 --route-length 40m --gap-fill-walk 4-neighbour --out "$out" --trace-cache "$traces"
# The tracking task's test cities: the test cities' geometry (same source, crop and seed) with one user and two 40 m
# routes (a pedestrian and a vehicle, 42 points), at the embedded ray count: about 5 MB each (docs/tracking.md).
routes=(--users 1 --routes 2 --route-length 40m)
uavdata simulate procedural:test --name test-routes --seed 2 "${routes[@]}" "${common[@]}"
uavdata simulate sionna:etoile --crop=-200,-200,200,200 --name etoile-routes --seed 4 "${routes[@]}" "${common[@]}"
uavdata simulate sionna:florence --crop=-200,-250,200,250 --name florence-routes --seed 5 "${routes[@]}" "${common[@]}"
# A validation twin for the tracking task on real geometry: etoile-val's crop and seed with the same one user and two
# 40 m routes (about 3 MB; florence-val's twin, about 5 MB, does not fit data/raw's budget beside it).
uavdata simulate sionna:etoile --crop=200,-200,400,200 --name etoile-val-routes --seed 6 "${routes[@]}" "${common[@]}"
# The tracking task's training corpus (trk-000 ... trk-003) and its validation city (trk-val): procedural mixed
# cities with one user and the same two 40 m routes a city, on the central 256 x 256 m of each (64 x 64 cells):
# about 2.5 MB and 7 minutes of the 2 cores each (docs/tracking.md).
small=(--extent 72,72,328,328)
uavdata simulate procedural:mixed --count 4 --name trk --seed 300 "${routes[@]}" "${small[@]}" "${common[@]}"
uavdata simulate procedural:mixed --name trk-val --seed 310 "${routes[@]}" "${small[@]}" "${common[@]}"
