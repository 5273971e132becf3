#!/usr/bin/env bash
# Re-measure every leaderboard row: each decider on each suite, submitted, then the leaderboard
# regenerated. Every row in leaderboards/ is what these commands produced (see the commit column).
# Usage: scripts/reproduce-leaderboard.sh [SUITE ...]   (default: all suites)
set -euo pipefail
cd "$(dirname "$0")/.."
suites=("$@")
[ ${#suites[@]} -gt 0 ] || suites=(table1 table1-reactive oncoming-2 oncoming-4 oncoming-8 dense urban-50 adversarial occluded)
deciders=(always-follow always-overtake rule-fsm fuzzy dqn double-dqn ppo bc cql oracle)
for suite in "${suites[@]}"; do
  for decider in "${deciders[@]}"; do
    out="results/$suite/$decider.json"
    overtakezoo eval --suite "$suite" --decider "$decider" --out "$out" --no-progress | tail -n 1
    overtakezoo submit --replace "$out"
  done
done
overtakezoo leaderboard
mkdir -p leaderboards/decision-maps
for decider in rule-fsm dqn; do
  overtakezoo decision-map --decider "$decider" --out "leaderboards/decision-maps/$decider.png"
done
