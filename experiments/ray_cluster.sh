#!/usr/bin/env bash
# The report on a Ray cluster of several nodes, simulated on one machine: a head that runs no task and two worker
# nodes of one CPU each (`ray start` processes), against the same report in one process. Prints each run's wall
# seconds and whether the tables and the episodes are identical; stops the cluster it started.
#
#   bash experiments/ray_cluster.sh [CITY] [EPISODES]      # default: test 300
#
# Run it from the repository root in the activated environment, with the city built and nothing else running.
set -euo pipefail
CITY=${1:-test}
EPISODES=${2:-300}
OUT=runs/ray-cluster
PORT=${PORT:-6390}
rm -rf "$OUT" && mkdir -p "$OUT"
common=(report --dataset "$CITY" --episodes "$EPISODES" --quiet)

SECONDS=0
uavrl "${common[@]}" --workers 1 --out "$OUT/one-process" > "$OUT/one-process.log"
echo "one process:      ${SECONDS} s wall"

trap 'ray stop --force > /dev/null 2>&1 || true' EXIT
# Ray's token authentication: every node and the driver read the token in ~/.ray/auth_token (made here if absent; on
# a real cluster, copy it to every node or set RAY_AUTH_TOKEN).
export RAY_AUTH_MODE=token
ray get-auth-token --generate > /dev/null
ray start --head --port "$PORT" --num-cpus 0 --include-dashboard false > "$OUT/head.log" 2>&1
for node in 1 2; do
    ray start --address "127.0.0.1:$PORT" --num-cpus 1 > "$OUT/node-$node.log" 2>&1
done
SECONDS=0
uavrl "${common[@]}" --ray-address "127.0.0.1:$PORT" --out "$OUT/two-nodes" > "$OUT/two-nodes.log"
echo "two worker nodes: ${SECONDS} s wall"

python - "$OUT" <<'EOF'
import sys
from pathlib import Path

import pandas as pd

out = Path(sys.argv[1])
for name in ("results.csv", "differences.csv", "episodes.parquet"):
    read = pd.read_parquet if name.endswith(".parquet") else pd.read_csv
    same = read(out / "one-process" / name).equals(read(out / "two-nodes" / name))
    print(f"{name}: {'identical' if same else 'DIFFERENT'}")
EOF
