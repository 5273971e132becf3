#!/usr/bin/env bash
# Re-measure every leaderboard row: each decider on each suite, submitted, then the leaderboard
# regenerated. Every row in leaderboards/ is what these commands produced (see the commit column).
# Usage: scripts/reproduce-leaderboard.sh [SUITE ...]   (default: all suites)
set -euo pipefail
cd "$(dirname "$0")/.."
suites=("$@")
[ ${#suites[@]} -gt 0 ] || suites=(table1 table1-reactive oncoming-2 oncoming-4 oncoming-8 dense urban-50 adversarial occluded
                                    duel platoon mixed-traffic)
deciders=(always-follow always-overtake rule-fsm fuzzy dqn double-dqn ppo bc cql ps-dqn oracle)
# The core suites also get every zoo member that overtakes behind the RSS shield (zoo/shield.py).
shielded=(rule-fsm+shield fuzzy+shield dqn+shield double-dqn+shield ppo+shield bc+shield cql+shield ps-dqn+shield)
# Multi-agent suites: self-play of every non-privileged zoo member (the oracle cannot share a road).
multi_deciders=(always-abort always-follow always-overtake rule-fsm fuzzy dqn double-dqn ppo bc cql ps-dqn)
for suite in "${suites[@]}"; do
  case "$suite" in duel|platoon|mixed-traffic) run=("${multi_deciders[@]}") ;; *) run=("${deciders[@]}" "${shielded[@]}") ;; esac
  for decider in "${run[@]}"; do
    out="results/$suite/$decider.json"
    overtakezoo eval --suite "$suite" --decider "$decider" --out "$out" --no-progress | tail -n 1
    overtakezoo submit --replace "$out"
  done
done
overtakezoo leaderboard
# The cross-play matrix (every non-privileged member against every other on duel; a few minutes).
overtakezoo crossplay --suite duel --jobs 2
mkdir -p leaderboards/decision-maps
for decider in rule-fsm dqn; do
  overtakezoo decision-map --decider "$decider" --out "leaderboards/decision-maps/$decider.png"
done
# The failure board (failure search of every zoo member, cross-table, failure maps; ~4 minutes).
overtakezoo failure-board --jobs 2
