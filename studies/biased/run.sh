#!/bin/bash
# Biased managers (paper Section 3.4): prefer goal vs prefer avoid, bias 0.15 (paper) and 3.0, seeds 0-2,
# over the same workers. Two at a time (one per core of a two-core machine).
#   studies/biased/run.sh WORKERS_FOLDER [RUN_FOLDER]   # then: python studies/biased/summarise.py RUN_FOLDER
set -u
export WORKERS=${1:?a train-workers folder} RUN=${2:-runs/biased}
mkdir -p "$RUN"
one() {
  bias=$1; prefer=$2; seed=$3; out=$RUN/b$bias-$prefer-s$seed
  hddpg-cli train-manager --workers "$WORKERS" --prefer $prefer --bias $bias --seed $seed \
    --out $out --no-progress --force > $out.log 2>&1 &&
  hddpg-cli evaluate $out/hierarchy.zip --episodes 20 --json $out.json >> $out.log 2>&1
}
export -f one
start=$(date +%s)
for bias in 0.15 3.0; do for seed in 0 1 2; do for prefer in goal avoid; do echo "$bias $prefer $seed"; done; done; done |
  xargs -P 2 -L 1 bash -c 'one $0 $1 $2'
echo "wall $(( $(date +%s) - start )) s" > "$RUN/done.txt"
