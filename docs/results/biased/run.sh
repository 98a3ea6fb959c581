#!/bin/bash
# Biased managers (paper Section 3.4): prefer goal vs prefer avoid, bias 0.15 (paper) and 3.0, seeds 0-2,
# over the same workers (docs/WORKERS.md evidence run). Two at a time (2 cores).
set -u
cd /work/main && source .venv/bin/activate
while pgrep -f "hddpg-cli benchmark" > /dev/null; do sleep 10; done
one() {
  bias=$1; prefer=$2; seed=$3; out=/work/runs/biased/b$bias-$prefer-s$seed
  hddpg-cli train-manager --workers /work/evidence/w --prefer $prefer --bias $bias --seed $seed \
    --out $out --no-progress --force > $out.log 2>&1 &&
  hddpg-cli evaluate $out/hierarchy.zip --episodes 20 --json $out.json >> $out.log 2>&1
}
export -f one
start=$(date +%s)
for bias in 0.15 3.0; do for seed in 0 1 2; do for prefer in goal avoid; do echo "$bias $prefer $seed"; done; done; done |
  xargs -P 2 -L 1 bash -c 'one $0 $1 $2'
echo "wall $(( $(date +%s) - start )) s" > /work/runs/biased/done.txt
