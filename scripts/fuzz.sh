#!/usr/bin/env bash
# Builds the libFuzzer targets of fuzz/ in build-fuzz/ (clang, ASan + UBSan + coverage),
# builds their seed corpora from the repository's own files, runs each target for a while and
# prints what each did. `make fuzz` runs this; docs/reliability.md ("Fuzzing") has the results.
#
#   scripts/fuzz.sh                      every target, FUZZ_SECONDS each
#   FUZZ_TARGETS="fuzz_pcd fuzz_las" FUZZ_SECONDS=60 scripts/fuzz.sh
#   scripts/fuzz.sh --minimize fuzz_las build-fuzz/artifacts/fuzz_las/crash-...   shrink a finding
#
# Environment: FUZZ_SECONDS (600 per target), FUZZ_TARGETS (all), FUZZ_JOBS (1 process per
# target; more runs libFuzzer's -fork), JOBS (compile jobs, 2), FUZZ_BUILD (build-fuzz).
# Exit status: 0 when every target ran clean, 1 when any found something (its input is kept in
# build-fuzz/artifacts/<target>/), 2 on a usage or build error.
set -euo pipefail

cd "$(dirname "$0")/.."
ROOT=$PWD
BUILD=${FUZZ_BUILD:-build-fuzz}
SECONDS_EACH=${FUZZ_SECONDS:-600}
JOBS=${JOBS:-2}
FUZZ_JOBS=${FUZZ_JOBS:-1}

# The limits every run uses (also for reproducing and minimising): a single allocation above
# 512 MiB is a finding (the targets set a 256 MiB memory budget, so a reader that checks its
# sizes never gets there), so is a process above 2 GiB or an input that takes over 10 s.
LIMITS=(-rss_limit_mb=2048 -malloc_limit_mb=512 -timeout=10)
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:symbolize=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
# Leaks inside libraries terramap cannot fix, each explained in the file.
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$ROOT/fuzz/lsan.supp:print_suppressions=0}

configure_and_build() {
  if [[ ! -f $BUILD/build.ninja ]]; then
    local launcher=()
    command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
    # Only what the readers need: no torch, Python, web page, benchmarks or tests.
    CC=clang CXX=clang++ cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTERRAMAP_FUZZ=ON \
      -DTERRAMAP_WITH_TORCH=OFF -DTERRAMAP_WITH_PYTHON=OFF -DTERRAMAP_WITH_WEB=OFF -DTERRAMAP_WITH_OCTOMAP=OFF \
      -DTERRAMAP_BUILD_BENCHMARKS=OFF -DTERRAMAP_BUILD_TESTS=OFF "${launcher[@]}"
  fi
  cmake --build "$BUILD" -j "$JOBS" --target fuzz_all
}

all_targets() {
  for f in fuzz/fuzz_*.cpp; do basename "$f" .cpp; done
}

# HDF5 1.10.8 sizes its metadata cache entries from a damaged file as they are (4 GiB and
# 8 EiB seen, inside H5Fopen, before terramap can check anything) and handles malloc returning
# NULL. For the episode target, malloc above 512 MiB returns NULL (as glibc does for the absurd
# sizes) instead of being a finding: HDF5 then fails and terramap says "cannot open as HDF5".
# terramap's own allocations go through operator new, which still reports them.
# docs/reliability.md ("Fuzzing") lists this as a known limit.
asan_options_of() {
  case $1 in
    fuzz_episode_h5) echo "$ASAN_OPTIONS:allocator_may_return_null=1:max_allocation_size_mb=512" ;;
    *) echo "$ASAN_OPTIONS" ;;
  esac
}

dict_of() {
  case $1 in
    fuzz_trajectory_*) echo fuzz/dict/fuzz_trajectory.dict ;;
    *) [[ -f fuzz/dict/$1.dict ]] && echo "fuzz/dict/$1.dict" ;;
  esac
  return 0
}

# Seeds: the files fuzz-seeds writes (every binary format, made small) and the YAML the
# repository has: configs/ and the YAML the unit tests parse (raw string literals R"(...)"),
# pipelines and scenarios told apart by their top-level keys.
make_seeds() {
  local seeds=$BUILD/seeds
  rm -rf "$seeds"
  "$BUILD/bin/fuzz-seeds" "$seeds"
  mkdir -p "$seeds/fuzz_pipeline_yaml" "$seeds/fuzz_scenario_yaml"
  python3 - "$seeds" <<'EOF'
import hashlib, pathlib, re, sys
out = pathlib.Path(sys.argv[1])
texts = [p.read_text() for p in sorted(pathlib.Path("configs").rglob("*.yaml"))]
texts += [p.read_text() for p in sorted(pathlib.Path("tests").rglob("*.yaml"))]
raw = re.compile(r'R"([A-Za-z_]{0,16})\((.*?)\)\1"', re.S)
for p in sorted(list(pathlib.Path("tests").rglob("*.cpp")) + list(pathlib.Path("plugins").rglob("tests/*.cpp"))):
    texts += [m.group(2) for m in raw.finditer(p.read_text(errors="replace"))]
for t in texts:
    if re.search(r"^machines:|^terrain:", t, re.M):
        kind = "fuzz_scenario_yaml"
    elif re.search(r"^(pipeline|map|source|outputs):", t, re.M):
        kind = "fuzz_pipeline_yaml"
    else:
        continue
    (out / kind / (hashlib.sha1(t.encode()).hexdigest()[:16] + ".yaml")).write_text(t)
EOF
}

run_target() {
  local t=$1 corpus=$BUILD/corpus/$1 artifacts=$BUILD/artifacts/$1 log=$BUILD/logs/$1.log
  mkdir -p "$corpus" "$artifacts" "$BUILD/logs"
  # The corpus keeps what earlier runs found; the seeds are (re)added, never replaced.
  [[ -d $BUILD/seeds/$t ]] && cp -n "$BUILD/seeds/$t"/* "$corpus"/ 2>/dev/null || true
  local dict opts=("${LIMITS[@]}" -max_total_time="$SECONDS_EACH" -print_final_stats=1 -artifact_prefix="$artifacts/")
  dict=$(dict_of "$t")
  [[ -n $dict ]] && opts+=(-dict="$dict")
  # -close_fd_mask=2: the libraries' own chatter goes; libFuzzer's and the sanitizers' reports stay.
  opts+=(-close_fd_mask=2)
  (( FUZZ_JOBS > 1 )) && opts+=(-fork="$FUZZ_JOBS" -ignore_crashes=0 -ignore_ooms=0 -ignore_timeouts=0)
  local before start rc=0
  before=$(ls "$artifacts" | wc -l)
  start=$(date +%s)
  echo "== $t: $BUILD/bin/$t ${opts[*]} $corpus" >&2
  ASAN_OPTIONS=$(asan_options_of "$t") "$BUILD/bin/$t" "${opts[@]}" "$corpus" >"$log" 2>&1 || rc=$?
  local took=$(( $(date +%s) - start ))
  local execs
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  [[ -z $execs ]] && execs=$(grep -oE '^#[0-9]+' "$log" | tail -1 | tr -d '#')
  local found outcome=clean
  found=$(ls -t "$artifacts" | head -1)
  if (( rc != 0 )) || (( $(ls "$artifacts" | wc -l) > before )); then
    outcome="FOUND (exit $rc): ${found:+$artifacts/$found}; log $log"
    FAILED=1
  fi
  printf '| %s | %s | %s | %s | %s |\n' "$t" "${execs:-?}" "$took" "$(ls "$corpus" | wc -l)" "$outcome" >>"$SUMMARY"
}

minimize() {
  local t=$1 input=$2 out=${2}.min
  ASAN_OPTIONS=$(asan_options_of "$t") "$BUILD/bin/$t" "${LIMITS[@]}" -minimize_crash=1 -runs=20000 \
    -exact_artifact_path="$out" "$input" || true
  echo "minimised input: $out ($(stat -c %s "$out") bytes)"
}

if [[ ${1:-} == --minimize ]]; then
  [[ $# -eq 3 ]] || { echo "usage: $0 --minimize TARGET INPUT" >&2; exit 2; }
  minimize "$2" "$3"
  exit 0
fi
[[ $# -eq 0 ]] || { echo "usage: $0 [--minimize TARGET INPUT] (settings through FUZZ_* variables)" >&2; exit 2; }

configure_and_build || exit 2
make_seeds || exit 2
targets=${FUZZ_TARGETS:-$(all_targets)}
SUMMARY=$BUILD/fuzz-summary.md
FAILED=0
{
  echo "fuzz run $(date -u +%Y-%m-%dT%H:%MZ), ${SECONDS_EACH} s per target, FUZZ_JOBS=$FUZZ_JOBS, $(git rev-parse --short HEAD 2>/dev/null)"
  echo
  echo "| target | executions | seconds | corpus files | outcome |"
  echo "| --- | --- | --- | --- | --- |"
} >"$SUMMARY"
for t in $targets; do
  [[ -x $BUILD/bin/$t ]] || { echo "no fuzz target '$t' (have: $(all_targets | tr '\n' ' '))" >&2; exit 2; }
  run_target "$t"
done
cat "$SUMMARY"
exit "$FAILED"
