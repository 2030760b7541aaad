#!/usr/bin/env bash
# Checks `morph farm-template openjd` with Open Job Description's own CLI (PyPI openjd-cli,
# installed into a cached venv outside the repo): the template passes `openjd check`; `openjd
# run` runs the morph to the end with progress reaching 100; a run cancelled part way (openjd
# sends SIGTERM, morph keeps its checkpoint) and run again resumes and ends with a
# final_mass.mgrid and morph.usdc bitwise those of the uninterrupted run. Usage:
# scripts/farm-check.sh (builds the release binary if needed).
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${MORPH_OPENJD_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/morph-openjd-venv}"
if ! "$venv/bin/openjd" --help >/dev/null 2>&1; then
  if ! { python3 -m venv "$venv" &&
    "$venv/bin/pip" install --quiet --disable-pip-version-check openjd-cli; }; then
    echo "farm check skipped: could not install openjd-cli into $venv" >&2
    exit 0
  fi
fi
oj="$venv/bin/openjd"
cargo build --release --quiet
morph="$PWD/target/release/morph"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work"
"$morph" farm-template openjd --template job.json "$OLDPWD/assets/sphere.obj" \
  "$OLDPWD/assets/two-lobes.obj" --resolution 20 -o ref >/dev/null
"$oj" check job.json
"$oj" run job.json --step Morph >ref.log 2>&1
grep -q "openjd_progress: 100.0" ref.log || { echo "farm check: progress never reached 100" >&2; exit 1; }
echo "ok   openjd run: the morph ran to the end, progress 100"
# Cancel part way, once a segment is checkpointed, then run the same job again.
"$oj" run job.json --step Morph -p Output=run >run1.log 2>&1 &
pid=$!
for _ in $(seq 1 1200); do
  [ -f run.partial/checkpoint/progress.json ] && break
  sleep 0.05
done
kill -INT "$pid"
wait "$pid" || true
if [ -f run/final_mass.mgrid ]; then
  echo "farm check: the run ended before it could be cancelled" >&2
  exit 1
fi
grep -q "interrupted by SIGTERM" run1.log || { echo "farm check: no SIGTERM reached morph" >&2; tail -5 run1.log >&2; exit 1; }
echo "ok   openjd cancel: morph stopped on SIGTERM and kept its checkpoint"
"$oj" run job.json --step Morph -p Output=run >run2.log 2>&1
grep -q "resumed from the checkpoint" run2.log || { echo "farm check: the second run did not resume" >&2; exit 1; }
"$morph" compare ref/final_mass.mgrid run/final_mass.mgrid --rtol 0 >/dev/null
cmp -s ref/morph.usdc run/morph.usdc
echo "ok   openjd run again: resumed, final_mass.mgrid and morph.usdc bitwise the uninterrupted run's"
