#!/usr/bin/env bash
# Re-measure every leaderboard row: each decider on each suite, submitted, then the leaderboard
# regenerated. Every row in leaderboards/ is what these commands produced (see the commit column).
# Usage: scripts/reproduce-leaderboard.sh [--members A,B] [SUITE ...]   (default: every member, all suites)
# --members re-measures only those members' rows (with their shielded rows) and what else shows them:
# the cross-play matrices, the failure board and the decision maps (after a member ships new weights).
set -euo pipefail
cd "$(dirname "$0")/.."
only=""
if [ "${1:-}" = --members ]; then only=",$2,"; shift 2; fi
suites=("$@")
# The driver populations (benchmark/suite_groups.py, DRIVERS): each a drivers-* and a mixed-drivers-* suite.
read -ra populations <<< "$(python -c "from overtakezoo.benchmark.suite_groups import DRIVERS; print(*DRIVERS)")"
[ ${#suites[@]} -gt 0 ] || suites=(table1 table1-reactive oncoming-2 oncoming-4 oncoming-8 dense urban-50 adversarial occluded
                                    duel platoon mixed-traffic
                                    "${populations[@]/#/drivers-}" "${populations[@]/#/mixed-drivers-}")
# The members come from the zoo's registry (zoo/base.py), the one list of them and their kinds.
members() { python -c "from overtakezoo import zoo; print(*(n for n in zoo.names($1) if $2))"; }
# Every member (the single-ego suites have no always-abort row, and joint-oracle plans multi-AV roads).
read -ra deciders <<< "$(members '' 'n not in ("always-abort", "joint-oracle")')"
# The core suites also get every zoo member that overtakes behind the RSS shield (zoo/members/shield.py).
read -ra shielded <<< "$(members '"wrapper"' True)"
# Multi-agent suites: self-play of every non-privileged zoo member (the oracle cannot share a road),
# and the joint oracle, their upper bound.
read -ra multi_deciders <<< "$(members '' 'zoo.member(n).kind != "privileged" or n == "joint-oracle"')"
for suite in "${suites[@]}"; do
  case "$suite" in
    duel|platoon|mixed-traffic|mixed-drivers-*) run=("${multi_deciders[@]}") ;;
    drivers-*) run=("${deciders[@]}") ;;  # the members against other drivers (not behind the shield)
    *) run=("${deciders[@]}" "${shielded[@]}") ;;
  esac
  for decider in "${run[@]}"; do
    [ -z "$only" ] || [[ "$only" == *",${decider%+shield},"* ]] || continue
    out="results/$suite/$decider.json"
    overtakezoo eval --suite "$suite" --decider "$decider" --out "$out" --no-progress | tail -n 1
    overtakezoo submit --replace "$out"
  done
done
overtakezoo leaderboard
[ $# -eq 0 ] || exit 0  # (suites named: only their rows)
# The cross-play matrices (every non-privileged member against every other: A drives the ego, B every
# other AV; a few minutes each).
for suite in duel platoon mixed-traffic; do
  overtakezoo crossplay --suite "$suite" --jobs 2 ${only:+--changed-only}
done
mkdir -p leaderboards/decision-maps
for decider in rule-fsm dqn; do
  [ -z "$only" ] || [[ "$only" == *",$decider,"* ]] || continue
  overtakezoo decision-map --decider "$decider" --out "leaderboards/decision-maps/$decider.png"
done
# The failure board (failure search of every zoo member, cross-table, failure maps; ~4 minutes).
overtakezoo failure-board --jobs 2
